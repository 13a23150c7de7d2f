"""Avatar benchmark: blendshape generation, glb build, and video rendering speed.

Targets: all 52 blendshapes in ≤ 10 s; a 60 s clip at 15 fps (900 frames)
rendered to MP4 with audio in ≤ 2 min on this CPU. The motion is the real BEAT clip
(``data/beat`` of the shared folder the command passes) with synthetic face weights
(a talking jaw and blinks). 20 s are rendered (2 s with ``quick``) and
``render_projected_60s_s`` = start-up + 900 frames at the measured rate, so the whole
bench stays within minutes.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from facecapges.arkit import N_BLENDSHAPES


def shared_file(shared: Path, rel: str) -> Path | None:
    p = Path(shared) / rel
    return p if p.exists() else None


def synthetic_face(T: int, fps: float) -> np.ndarray:
    """(T, 52) weights: jawOpen at speech-like rate, blinks every 3 s, a slow smile."""
    from facecapges.arkit import arkit_index

    t = np.arange(T) / fps
    w = np.zeros((T, N_BLENDSHAPES), np.float32)
    w[:, arkit_index("jawOpen")] = 0.35 * np.clip(np.sin(2 * np.pi * 3.1 * t) + 0.3, 0, None)
    blink = ((t % 3.0) < 0.15).astype(np.float32)
    w[:, arkit_index("eyeBlinkLeft")] = blink
    w[:, arkit_index("eyeBlinkRight")] = blink
    w[:, arkit_index("mouthSmileLeft")] = w[:, arkit_index("mouthSmileRight")] = 0.3 + 0.3 * np.sin(0.5 * t)
    return w


def run(quick: bool, shared: Path) -> dict:
    from facecapges.avatar.blendshapes import arkit_blendshapes
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf
    from facecapges.avatar.render.browser import chromium_version
    from facecapges.avatar.render.video import bvh_quaternions, our_avatar, render_video
    from facecapges.io.bvh import read_bvh

    out: dict = {}
    t0 = time.perf_counter()
    shapes = arkit_blendshapes(compare=False)
    out["blendshapes_52_s"] = round(time.perf_counter() - t0, 3)
    out["blendshapes_target_s"] = 10.0
    bvh_path = shared_file(shared, "data/beat/2_scott_0_1_1.bvh")
    if bvh_path is None:
        from facecapges.errors import UserError

        raise UserError(f"{shared}: the render benchmark needs data/beat/2_scott_0_1_1.bvh")
    bvh = read_bvh(bvh_path)
    t0 = time.perf_counter()
    glb = b"".join(avatar_to_gltf(default_avatar(bvh.skeleton)).save_to_bytes())
    out["avatar_build_s"] = round(time.perf_counter() - t0, 3)
    out["avatar_glb_bytes"] = len(glb)
    seconds = 2.0 if quick else 20.0  # the 60 s figure is projected from the measured rate
    T = int(round(seconds * bvh.fps))
    reps = (T + bvh.n_frames - 1) // bvh.n_frames
    motion = np.concatenate([bvh.motion] * reps)[:T]
    quats = bvh_quaternions(bvh.skeleton.names, bvh.skeleton, motion)
    wav = shared_file(shared, "data/beat/2_scott_0_1_1.wav")
    with tempfile.TemporaryDirectory() as tmp:
        figures = render_video(
            our_avatar(glb),
            quats,
            synthetic_face(T, bvh.fps),
            bvh.fps,
            Path(tmp) / "bench.mp4",
            audio=wav,
            progress=False,
        )
        mp4_bytes = (Path(tmp) / "bench.mp4").stat().st_size
    out.update(
        {
            "clip_s": seconds,
            "frames": T,
            "fps": bvh.fps,
            "size": "x".join(map(str, figures["size"])),
            "render_total_s": round(figures["total_s"], 2),
            "render_frames_per_s": round(figures["frames_per_s"], 2),
            "render_target_s_for_60s": 120.0,
            "render_projected_60s_s": round(figures["startup_s"] + 60.0 * bvh.fps / figures["frames_per_s"], 1),
            "mp4_bytes": mp4_bytes,
            "chromium": chromium_version(),
            "n_blendshapes": len(shapes.names),
        }
    )
    return out
