#!/usr/bin/env bash
# Set up what the test suite needs beyond the Python dependencies (called by `make test`, not by the demo).
# Idempotent.
#   - Debian `blender` (3.4) + `python3-numpy` (its glTF importer needs numpy; Debian only recommends
#     it): tests/test_blender_import.py imports our BVH and GLB in headless Blender, the consumer
#     users feed them to.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
command -v blender >/dev/null 2>&1 || need+=(blender)
/usr/bin/python3 -c "import numpy" >/dev/null 2>&1 || need+=(python3-numpy)
if [ "${#need[@]}" -gt 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends "${need[@]}"
fi
echo "test setup ok: $(blender --version 2>/dev/null | head -n 1)"
