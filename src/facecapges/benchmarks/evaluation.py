"""Speed of the evaluation tools (``facecapges bench --only evaluation``).

Figures, on the shared BEAT clip (``../shared/data/beat/2_scott_0_1_1``):

* ``skeleton_video_s_per_min`` — seconds to render and encode 60 s of 15 fps video
  with two skeleton panels and audio (:mod:`facecapges.avatar.render.skeleton_video`);
  target ≤ 60 s. ``skeleton_video_fps`` is the same as frames per second.
* ``fgd_train_s_per_epoch_per_1k_windows`` — FGD autoencoder training time for one
  epoch over 1000 windows (B = 256, one region); ×400 epochs is the default run.
* ``fgd_embed_windows_per_s`` — encoder throughput when embedding motion for FGD.
* ``frechet_128d_ms`` — eq. 5.3 on 128-d features (symmetric eigh form).
* ``beat_align_control_s_per_min`` — matched + 30 shifted BeatAlign scores of one
  minute of motion and audio (dominated by onset detection of the 31 audio versions).

Peer-architecture timing, under ``"peer_timing"`` (:func:`peer_timing`; random
weights, batch 1, one thread, the same speech-like inputs for all):

* ``facecapges_step_ms_p50`` — FaceCapGes (default :class:`ModelConfig`) frame by frame
  through :class:`facecapges.network.streaming.NetworkStream` (the live path).
* ``camn_online_ms_p50`` — our CaMN (:mod:`facecapges.evaluation.camn`, CaMN's sizes)
  used online: for every output frame it is re-run over the 34-frame window ending at
  that frame (the 16 frames before it seeded with the previous outputs) and the last
  frame is kept — the only way an offline segment decoder can run without look-ahead.
* ``camn_offline_ms_per_frame`` — CaMN decoding a whole clip (``offline_seconds``) in one
  pass, per output frame.
* ``camn_online_over_facecapges`` and ``camn_offline_over_facecapges`` — the ratios,
  measured in the same run with the timed loops interleaved in blocks (the machine's
  load hits them alike).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from facecapges.timing import AUDIO_SR, MODEL_FPS


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

    from facecapges.avatar.render.skeleton_video import render_skeleton_video
    from facecapges.evaluation import beat_align as ba
    from facecapges.evaluation.fgd import (
        FGDAutoencoder,
        FGDConfig,
        frechet_distance_features,
        make_windows,
        reconstruction_loss,
    )
    from facecapges.skeleton import UPPER_BODY

    skel, pose, audio, sr, source = _data(shared)
    fps = float(MODEL_FPS)
    n = 900  # 60 s at 15 fps
    out: dict = {"data": source}
    # skeleton video: 60 s, 2 panels, audio
    with tempfile.TemporaryDirectory() as td:
        wav = Path(td) / "a.wav"
        sf.write(wav, audio[: 60 * sr], sr)
        frames = 150 if quick else n
        t0 = time.perf_counter()
        render_skeleton_video(
            [pose[:frames], pose[57 : 57 + frames]], ["real", "other"], skel, Path(td) / "v.mp4", fps, wav
        )
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
    out["peer_timing"] = peer_timing(quick)
    return out


def _speechlike(n_frames: int, spf: int, seed: int = 0) -> np.ndarray:
    """(n_frames, spf) float32: harmonics under a syllable-rate envelope, plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames * spf) / AUDIO_SR
    env = 0.5 * (1 + np.sin(2 * np.pi * 4.0 * t))
    wave = env * (0.2 * np.sin(2 * np.pi * 140 * t) + 0.1 * np.sin(2 * np.pi * 280 * t))
    return (wave + 0.01 * rng.standard_normal(t.size)).astype(np.float32).reshape(n_frames, spf)


def peer_timing(quick: bool = False) -> dict:
    """FaceCapGes streaming vs CaMN online (34-frame window per frame) and offline, per output frame."""
    import torch

    from facecapges.evaluation.camn import CaMN, CaMNConfig
    from facecapges.network.config import ModelConfig
    from facecapges.network.network import FaceCapGes
    from facecapges.network.streaming import NetworkStream

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        torch.manual_seed(0)
        cfg = ModelConfig()
        N, L, spf = cfg.n_history, 34, cfg.samples_per_frame
        ours = NetworkStream(FaceCapGes(cfg), np.zeros((N, cfg.n_joints, 6), np.float32))
        camn = CaMN(cfg).eval()
        blocks, per_block = (2, 3) if quick else (4, 5)  # CaMN online frames per block
        T = L + blocks * per_block
        audio = _speechlike(T, spf)
        face = np.zeros((T, cfg.n_face), np.float32)
        head = np.tile(np.array([1, 0, 0, 0, 1, 0], np.float32), (T, 1))
        a_t, f_t, h_t = (torch.from_numpy(x) for x in (audio, face, head))
        poses = torch.zeros(T, cfg.pose_dim)
        ours_ms: list[float] = []
        camn_ms: list[float] = []
        with torch.inference_mode():
            for t in range(L - 1):  # warm both up
                ours.step(audio[t], face[t], head[t])
            camn(a_t[None, :L], f_t[None, :L], h_t[None, :L], poses[None, :N])
            t = L - 1
            for _ in range(blocks):
                for _ in range(per_block * 10):  # ours is fast: more frames per block
                    i = t % T
                    t0 = time.perf_counter()
                    ours.step(audio[i], face[i], head[i])
                    ours_ms.append((time.perf_counter() - t0) * 1000)
                    t += 1
                for _ in range(per_block):
                    e = L + len(camn_ms)  # the window ends at frame e − 1
                    t0 = time.perf_counter()
                    out = camn(
                        a_t[None, e - L : e], f_t[None, e - L : e], h_t[None, e - L : e], poses[None, e - L : e - L + N]
                    )
                    poses[e - 1] = out[0, -1]
                    camn_ms.append((time.perf_counter() - t0) * 1000)
            secs = 10 if quick else 60
            n_off = secs * cfg.fps
            a_off = torch.from_numpy(_speechlike(N + n_off, spf, 1))[None]
            f_off, h_off = (
                torch.zeros(1, N + n_off, cfg.n_face),
                torch.from_numpy(np.tile(head[:1], (N + n_off, 1)))[None],
            )
            t0 = time.perf_counter()
            camn(a_off, f_off, h_off, torch.zeros(1, N, cfg.pose_dim))
            off_ms = (time.perf_counter() - t0) * 1000 / n_off
    finally:
        torch.set_num_threads(threads)
    ours_p50 = float(np.median(ours_ms))
    online_p50 = float(np.median(camn_ms))
    return {
        "facecapges_step_ms_p50": round(ours_p50, 3),
        "camn_online_ms_p50": round(online_p50, 2),
        "camn_offline_ms_per_frame": round(off_ms, 3),
        "offline_seconds": secs,
        "camn_online_over_facecapges": round(online_p50 / ours_p50, 1),
        "camn_offline_over_facecapges": round(off_ms / ours_p50, 2),
        "camn_params_M": round(sum(p.numel() for p in camn.parameters()) / 1e6, 2),
        "camn_config": {k: getattr(CaMNConfig(), k) for k in ("hidden", "layers", "audio_f", "facial_f")},
        "frames_timed": {"facecapges": len(ours_ms), "camn_online": len(camn_ms)},
    }
