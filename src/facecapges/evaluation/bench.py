"""Speed of the evaluation tools (``facecapges bench --only evaluation``).

Figures, on the shared BEAT clip (``../shared/data/beat/2_scott_0_1_1``):

* ``skeleton_video_s_per_min`` — seconds to render and encode 60 s of 15 fps video
  with two skeleton panels and audio (:mod:`facecapges.outputs.skeleton_video`);
  target ≤ 60 s. ``skeleton_video_fps`` is the same as frames per second.
* ``fgd_train_s_per_epoch_per_1k_windows`` — FGD autoencoder training time for one
  epoch over 1000 windows (B = 256, one region); ×400 epochs is the default run.
* ``fgd_embed_windows_per_s`` — encoder throughput when embedding motion for FGD.
* ``frechet_128d_ms`` — eq. 5.3 on 128-d features (symmetric eigh form).
* ``beat_align_control_s_per_min`` — matched + 30 shifted BeatAlign scores of one
  minute of motion and audio (dominated by onset detection of the 31 audio versions).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np


def _data(shared_dir: Path):
    """Skeleton, poses (T, 47, 6), audio and sr of the shared BEAT clip (in the shared folder)."""
    import soundfile as sf

    from facecapges.errors import UserError
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import motion_to_pose

    shared = Path(shared_dir) / "data" / "beat"
    bvh_p, wav_p = shared / "2_scott_0_1_1.bvh", shared / "2_scott_0_1_1.wav"
    if not (bvh_p.is_file() and wav_p.is_file()):
        raise UserError(f"{shared}: the evaluation benchmark needs the shared BEAT clip 2_scott_0_1_1 (.bvh, .wav)")
    b = read_bvh(bvh_p)
    audio, sr = sf.read(wav_p, dtype="float32")
    return b.skeleton, motion_to_pose(b.skeleton, b.motion)[0], audio, sr, "shared BEAT clip 2_scott_0_1_1"


def run(quick: bool, shared: Path) -> dict:
    import soundfile as sf
    import torch

    from facecapges.evaluation import beat_align as ba
    from facecapges.evaluation.fgd import FGDAutoencoder, FGDConfig, frechet_distance_features, make_windows, \
        reconstruction_loss
    from facecapges.outputs.skeleton_video import render_skeleton_video
    from facecapges.skeleton import UPPER_BODY

    skel, pose, audio, sr, source = _data(shared)
    fps = 15.0
    n = 900  # 60 s at 15 fps
    out: dict = {"data": source}
    # skeleton video: 60 s, 2 panels, audio
    with tempfile.TemporaryDirectory() as td:
        wav = Path(td) / "a.wav"
        sf.write(wav, audio[: 60 * sr], sr)
        frames = 150 if quick else n
        t0 = time.perf_counter()
        render_skeleton_video([pose[:frames], pose[57:57 + frames]], ["real", "other"], skel, Path(td) / "v.mp4", fps,
                              wav)
        dt = time.perf_counter() - t0
    out["skeleton_video_s_per_min"] = round(dt * n / frames, 2)
    out["skeleton_video_fps"] = round(frames / dt, 1)
    # FGD training epoch and embedding throughput
    cfg = FGDConfig()
    model = FGDAutoencoder(cfg, UPPER_BODY)
    wins = torch.from_numpy(make_windows([pose], cfg.window, cfg.stride))
    opt = torch.optim.SGD(model.parameters(), lr=cfg.lr, momentum=cfg.momentum)
    reps = 1 if quick else 3
    t0 = time.perf_counter()
    for _ in range(reps):
        loss = reconstruction_loss(model(wins), wins)
        opt.zero_grad()
        loss.backward()
        opt.step()
    dt = (time.perf_counter() - t0) / reps
    out["fgd_train_s_per_epoch_per_1k_windows"] = round(dt * 1000 / len(wins), 2)
    with torch.no_grad():
        t0 = time.perf_counter()
        for _ in range(reps):
            model.encode(wins)
        out["fgd_embed_windows_per_s"] = round(reps * len(wins) / (time.perf_counter() - t0), 1)
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(800, 128)), rng.normal(size=(700, 128))
    t0 = time.perf_counter()
    frechet_distance_features(a, b)
    out["frechet_128d_ms"] = round((time.perf_counter() - t0) * 1000, 2)
    # BeatAlign control on one minute
    offsets = range(2, 61, 2) if not quick else range(2, 61, 20)
    m = 300 if quick else n  # quick: 20 s of motion, scaled to a minute
    t0 = time.perf_counter()
    c = ba.beat_align_control(pose[:m], audio, sr, fps, offsets_s=offsets)
    out["beat_align_control_s_per_min"] = round((time.perf_counter() - t0) * n / m, 2)
    out["beat_align_offsets"] = len(c.offsets_s)
    return out
