"""Benchmark of the data path: reading BEAT files, building a cache, loading a clip.

Runs on the shared sample (``data/beat`` of the shared folder the command passes); figures
are wall-clock seconds on this machine. ``quick`` does one repetition instead of three.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

CLIP = "2_scott_0_1_1"


def _best(fn, reps: int) -> float:
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(quick: bool, shared: Path) -> dict:
    """Seconds for read_bvh, motion_to_pose, load_audio, a full prepare and Cache.load of the sample;
    retargeting speed of the ZEGGS take and the 9-joint reader (shared ``data/zeggs``, ``data/zeggs9``)."""
    from facecapges.data.cache import Cache
    from facecapges.data.prepare import prepare
    from facecapges.errors import UserError
    from facecapges.io.audio import load_audio
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import motion_to_pose

    sample_dir = Path(shared) / "data" / "beat"
    bvh_path, wav_path = sample_dir / f"{CLIP}.bvh", sample_dir / f"{CLIP}.wav"
    if not bvh_path.exists() or not wav_path.exists():
        raise UserError(f"{sample_dir}: the data benchmark needs the shared clip {CLIP} (.bvh, .wav)")
    reps = 1 if quick else 3
    bvh = read_bvh(bvh_path)
    result: dict[str, Any] = {
        "clip": CLIP,
        "frames": bvh.n_frames,
        "read_bvh_s": round(_best(lambda: read_bvh(bvh_path), reps), 4),
        "motion_to_pose_s": round(_best(lambda: motion_to_pose(bvh.skeleton, bvh.motion), reps), 4),
        "load_audio_s": round(_best(lambda: load_audio(wav_path), reps), 4),
    }
    tmp = Path(tempfile.mkdtemp(prefix="facecapges-bench-"))
    try:
        out = tmp / "cache"
        result["prepare_s"] = round(
            _best(lambda: prepare(sample_dir, out, speakers=[2], force=True, progress=False), reps), 4
        )
        result["prepare_frames_per_s"] = round(bvh.n_frames / result["prepare_s"], 1)
        cache = Cache(out)
        result["cache_load_ms"] = round(1000 * _best(lambda: cache.load(CLIP), reps), 2)
        result["cache_mb"] = round(sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6, 2)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result.update(_other_sources(bvh.skeleton, reps, Path(shared) / "data"))
    return result


def _other_sources(target, reps: int, data_dir: Path) -> dict:
    """Frames per second of retargeting the ZEGGS BVH (its own rate) and reading a 9-joint take (to 15 fps)."""
    from facecapges.data.joints9 import read_joints9
    from facecapges.data.retarget import retarget_bvh
    from facecapges.io.bvh import read_bvh

    out: dict = {}
    zeggs = data_dir / "zeggs" / "067_Speech_2_x_1_0.bvh"
    if zeggs.exists():
        n = read_bvh(zeggs).n_frames
        out["retarget_zeggs_frames_per_s"] = round(n / _best(lambda: retarget_bvh(zeggs, target), reps), 1)
    take = data_dir / "zeggs9" / "001_Neutral_0_x_1_0.npy"
    if take.exists():
        n = read_joints9(take, target).n_frames
        out["joints9_frames_per_s"] = round(n / _best(lambda: read_joints9(take, target), reps), 1)
    return out
