"""VRM benchmark: what driving a VRM costs per frame, and the VRM Animation writer.

* ``retarget_frame_ms`` — one live frame onto a VRM's normalised bones (BEAT forward
  kinematics + rest-pose correction; what ``live --web --avatar`` adds per frame),
  median of many; ``retarget_900_ms`` — a 60 s clip at 15 fps in one call (``render``);
* ``presets_frame_ms`` / ``perfect_sync_frame_ms`` — one frame's face onto VRM presets
  (the ARKit → preset mapping, NNLS visemes) or perfect-sync expressions;
* ``vrma_900_s`` and ``vrma_900_bytes`` — writing that clip (+ face) as ``.vrma``.

The target is the BEAT skeleton seen as a VRM (its own rest pose); the motion is the
shared BEAT take when present, else the rest pose with a sway.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from facecapges.skeleton import N_JOINTS
from facecapges.timing import MODEL_FPS


def run(quick: bool, shared: Path) -> dict:
    from facecapges.arkit import ARKIT_NAMES
    from facecapges.avatar.retarget import Retargeter, upper_body_locals
    from facecapges.avatar.vrm.animation import beat_model, write_vrma
    from facecapges.avatar.vrm.expressions import PRESET_BINDS, ExpressionMap
    from facecapges.avatar.vrm.view import bvh_local_matrices
    from facecapges.benchmarks.render import shared_file, synthetic_face

    bvh = shared_file(shared, "data/beat/2_scott_0_1_1.bvh")
    if bvh is not None:
        from facecapges.io.bvh import read_bvh

        m = read_bvh(bvh)
        skel, L, fps = m.skeleton, bvh_local_matrices(m.skeleton, m.motion[:900]), m.fps
    else:
        from facecapges.styles import load_skeleton

        skel, fps = load_skeleton(), float(MODEL_FPS)
        L = np.broadcast_to(np.eye(3), (900, skel.n_joints, 3, 3)).copy()
    model = beat_model(skel)
    rt = Retargeter(skel, model)
    face = synthetic_face(len(L), fps)
    presets = ExpressionMap(list(PRESET_BINDS))
    sync = ExpressionMap(ARKIT_NAMES)
    n = 50 if quick else 300
    q47 = np.tile(np.array([1.0, 0, 0, 0]), (N_JOINTS, 1))

    def med(fn) -> float:
        ts = []
        for k in range(n):
            t0 = time.perf_counter()
            fn(k)
            ts.append(time.perf_counter() - t0)
        return round(float(np.median(ts)) * 1000, 4)

    out = {
        "bones": len(rt.bones),
        "retarget_frame_ms": med(lambda k: rt(upper_body_locals(skel, q47[None]))),
        "presets_frame_ms": med(lambda k: presets(face[k % len(face)][None])),
        "perfect_sync_frame_ms": med(lambda k: sync(face[k % len(face)][None])),
    }
    t0 = time.perf_counter()
    rt(L)
    out["retarget_900_ms"] = round((time.perf_counter() - t0) * 1000, 2)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        p = write_vrma(Path(tmp) / "b.vrma", skel, L, fps, face, "presets")
        out["vrma_900_s"] = round(time.perf_counter() - t0, 3)
        out["vrma_900_bytes"] = p.stat().st_size
    return out
