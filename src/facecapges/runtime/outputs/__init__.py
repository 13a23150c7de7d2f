"""Where the runtime's frames go: file recorders, VMC, the upsampler, the browser viewers and their wire format."""
