"""Switch the face input off in a prepared cache (in place): every clip's face track zeroed.

    python scripts/cache_without_face.py CACHE

The shipped network style `beat2-scott-demo` is trained on audio and head motion only (its BEAT
BVH take has no face capture). A BEAT2 take's face is a jawOpen track alone (``face_source: "jaw"``,
:mod:`facecapges.data.beat2`): trained with it, the style would standardise the 51 other blendshapes
by a spread of zero, and a live face's blinks and smiles would reach it tens of sd out of range.
With every face zeroed the trainer stores a face scale of 0 (the style ignores a live face), as the
previous build did.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: cache_without_face.py CACHE")
    cache = Path(sys.argv[1])
    index_path = cache / "index.json"
    index = json.loads(index_path.read_text(encoding="utf-8"))
    for entry in index["clips"]:
        path = cache / entry["file"]
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["face"] = np.zeros_like(arrays["face"])
        arrays["face_present"] = np.array(False)
        np.savez_compressed(path, **arrays)
        entry["has_face"], entry["face_source"] = False, None
    index_path.write_text(json.dumps(index, indent=1), encoding="utf-8")
    print(f"{cache}: face off in {len(index['clips'])} clip(s)")


if __name__ == "__main__":
    main()
