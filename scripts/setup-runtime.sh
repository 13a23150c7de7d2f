#!/usr/bin/env bash
# Set up what the real-time runtime needs beyond the Python dependencies. Idempotent.
#   - Debian `libportaudio2`: the PortAudio library the `sounddevice` wheel loads for microphones
#     (`facecapges live --mic`). Without it a microphone cannot open (a clear error, exit 2).
#   - The browser viewer reuses the avatar set-up (chromium for tests, npm three 0.187.0):
#     scripts/setup-avatar.sh.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q 'libportaudio\.so\.2'; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends libportaudio2
fi
echo "runtime setup ok: $(ldconfig -p | grep -m1 'libportaudio\.so\.2' | awk '{print $NF}')"
