"""Where the runtime's frames come from: video files, camera, microphone, Live Link Face."""
