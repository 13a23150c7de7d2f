"""The training recipe: audio features, input normalisation, head frame, one trainer for every variant."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from facecapges import rotations as rot
from facecapges.network.config import ModelConfig
from tolerances import assert_rotations_close

TINY = dict(audio_frontend_channels=(4, 8, 8), audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8,
            face_dim=8, lstm_hidden=16, mlp_hidden=16, disc_channels=8)
SR, SPF = 16000, 1067


def _speech_like(seconds: float, seed: int = 0) -> np.ndarray:
    """Voiced bursts (harmonics of a gliding F0) separated by pauses, 16 kHz."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * SR)) / SR
    f0 = 120 + 30 * np.sin(2 * np.pi * 0.7 * t)
    phase = 2 * np.pi * np.cumsum(f0) / SR
    voiced = sum(np.sin(k * phase) / k for k in range(1, 6))
    env = (np.sin(2 * np.pi * 1.3 * t) > 0.2).astype(float)
    return (0.3 * env * voiced + 0.003 * rng.normal(size=t.shape)).astype(np.float32)


# ------------------------------------------------------------------ audio features
def test_mel_features_match_librosa_and_find_f0():
    import librosa

    from facecapges.network.audio_features import FEATURE_DIM, N_MELS, AudioFeatures

    feats = AudioFeatures(SR, SPF)
    rng = np.random.default_rng(0)
    frame = rng.normal(0, 0.1, SPF).astype(np.float32)
    out = feats(torch.from_numpy(frame)[None]).numpy()[0]
    assert out.shape == (FEATURE_DIM,)
    ref = librosa.feature.melspectrogram(y=frame, sr=SR, n_fft=512, hop_length=128, center=False, n_mels=N_MELS)
    np.testing.assert_allclose(out[:N_MELS], 10 * np.log10(np.maximum(ref.mean(-1), 1e-10)), atol=1e-3)
    np.testing.assert_allclose(out[N_MELS], 10 * np.log10(np.mean(frame.astype(np.float64) ** 2)), atol=1e-3)
    for f0 in (90.0, 150.0, 240.0):  # a voiced frame: log2(F0/100) within 2 %, voicing high
        tone = np.sin(2 * np.pi * f0 * np.arange(SPF) / SR).astype(np.float32)
        v = feats(torch.from_numpy(tone)[None]).numpy()[0]
        assert 2 ** v[N_MELS + 1] * 100 == pytest.approx(f0, rel=0.02) and v[N_MELS + 2] > 0.8
    noise = feats(torch.from_numpy(rng.normal(size=SPF).astype(np.float32))[None]).numpy()[0]
    assert noise[N_MELS + 1] == 0.0 and noise[N_MELS + 2] < 0.3  # unvoiced: no F0


def test_stored_mel_basis_is_librosas():
    """The Mel filter bank kept in the package's assets (so ``live`` need not import Librosa) is Librosa's, exactly."""
    import librosa

    from facecapges.network.audio_features import N_FFT, N_MELS, mel_basis, mel_basis_file

    assert mel_basis_file(SR).is_file()
    np.testing.assert_array_equal(mel_basis(SR), librosa.filters.mel(sr=SR, n_fft=N_FFT, n_mels=N_MELS))


def test_mel_features_streaming_equal_offline_and_causal():
    """A clip's features as (T, S) frames equal the per-frame ones; changing the future changes nothing."""
    from facecapges.network.audio_features import AudioFeatures
    from facecapges.timing import frame_audio

    feats = AudioFeatures(SR, SPF)
    audio = _speech_like(3.0)
    T = 45
    frames = torch.from_numpy(frame_audio(audio, T, 15, SR))
    offline = feats(frames).numpy()
    stream = np.stack([feats(frames[t:t + 1])[0].numpy() for t in range(T)])
    # one frame against 45 (batched FFTs): the powers' float32 rounding, a few ulps through a 1024-point FFT and
    # the Mel sums; 1e-4 dB is a relative power error of 2.3e-5 (~190 ulps); F0 (octaves) and voicing are ≤ 1
    np.testing.assert_allclose(stream, offline, atol=1e-4)
    later = frames.clone()
    later[30:] = torch.randn_like(later[30:])
    np.testing.assert_array_equal(feats(later).numpy()[:30], offline[:30])


def test_mel_features_native_schedule_equals_torch():
    """The streaming kernel's small-batch schedule of the features (native loops between the same
    FFTs) gives forward's values: speech, noise, tones, silence, one frame or many."""
    from facecapges.network.audio_features import N_MELS, AudioFeatures
    from facecapges.timing import frame_audio

    feats = AudioFeatures(SR, SPF)
    rng = np.random.default_rng(3)
    tones = [np.sin(2 * np.pi * f0 * np.arange(SPF) / SR) for f0 in (70.0, 130.0, 390.0)]
    frames = np.concatenate([frame_audio(_speech_like(2.0, seed=2), 30, 15, SR), rng.normal(0, 0.2, (5, SPF)),
                             np.stack(tones), np.zeros((2, SPF))]).astype(np.float32)
    x = torch.from_numpy(frames)
    ref = feats(x).numpy()
    for got in (feats.forward_native(x).numpy(), np.concatenate([feats.forward_native(x[t:t + 1]).numpy()
                                                                 for t in range(len(x))])):
        # the same FFTs, then loops that sum in another order: float32 rounding of the powers (1e-4 dB is a
        # relative error of 2.3e-5, ~190 ulps); F0 is read at the same best lag and voicing (≤ 1) is one ratio
        # of two such sums, a few ulps: 1e-6 is 8 ulps at 1
        np.testing.assert_allclose(got[:, : N_MELS + 1], ref[:, : N_MELS + 1], atol=1e-4, rtol=0)  # dB
        np.testing.assert_allclose(got[:, N_MELS + 1 :], ref[:, N_MELS + 1 :], atol=1e-6, rtol=0)  # F0, voicing
    assert (ref[:, N_MELS + 2] >= 0.3).sum() > 10  # voiced frames were compared


def test_mel_model_streams_like_its_training_rollout():
    from facecapges.network.network import FaceCapGes
    from facecapges.network.streaming import NetworkStream

    torch.manual_seed(0)
    model = FaceCapGes(ModelConfig(audio_repr="mel", **TINY)).eval()
    cfg, N, T = model.cfg, model.cfg.n_history, 40
    from facecapges.timing import frame_audio

    a = torch.from_numpy(frame_audio(_speech_like(3.0, seed=1), T, 15, SR))[None]
    f, h = torch.rand(1, T, 52), torch.randn(1, T, 6)
    p = torch.randn(1, T, cfg.pose_dim) * 0.3
    with torch.no_grad():
        ref = model.rollout(model.encode(a, f, h), p[:, :N])[0].numpy()
    g = NetworkStream(model, np.zeros((N, 47, 6), np.float32))
    for t in range(N):
        g.warmup(a[0, t].numpy(), f[0, t].numpy(), h[0, t].numpy(), p[0, t].numpy())
    out = np.stack([g.step(a[0, t].numpy(), f[0, t].numpy(), h[0, t].numpy()) for t in range(N, T)])
    # one frame at a time against the whole clip (batched FFTs, other kernels): float32 rounding, 0.01° (tolerances.py)
    assert_rotations_close(out, ref.reshape(out.shape), what="streaming against the rollout")


# --------------------------------------------------------------------- head frame
def test_skeleton_head_maps_to_camera_frame_around_the_speaker_mean():
    from facecapges.capture.head_pose import skeleton_head_to_camera
    from facecapges.rotations import angles_to_matrix, head_angles, mean_rotation

    rng = np.random.default_rng(0)
    rest = angles_to_matrix(0.0, np.radians(13.0), 0.0)  # the speaker's head, pitched 13° on average
    yaws = np.radians(rng.normal(0, 5, 200))
    R = np.stack([angles_to_matrix(y, 0.0, 0.0) @ rest for y in yaws])  # turns about the vertical axis
    ref = mean_rotation(rot.matrix_to_rot6d(R))
    assert np.degrees(head_angles(rot.rot6d_to_matrix(ref))[1]) == pytest.approx(13.0, abs=0.5)
    cam = skeleton_head_to_camera(rot.matrix_to_rot6d(R), ref)
    ang = head_angles(rot.rot6d_to_matrix(cam.astype(np.float64)))
    # the mean head is "facing the camera"; a turn of the speaker is the same turn of a user
    np.testing.assert_allclose(ang[:, 0], yaws - yaws.mean(), atol=np.radians(0.3))
    np.testing.assert_allclose(ang[:, 1:], 0.0, atol=np.radians(0.3))
    np.testing.assert_allclose(skeleton_head_to_camera(ref, ref), rot.identity_rot6d(), atol=1e-6)


# --------------------------------------------------------------- what a style saw
def _clip(T: int = 160, seed: int = 0, face: bool = False):
    from facecapges.training.segments import ClipArrays

    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    pose = (np.sin(t / 5.0 + np.arange(47)[None, :, None] / 7.0) * 0.3 + rot.identity_rot6d()).astype(np.float32)
    pitch = rot.matrix_to_rot6d(rot.euler_to_matrix(np.stack([np.full(T, 0.23), 0.05 * rng.normal(size=T),
                                                               np.zeros(T)], 1), "XYZ")).astype(np.float32)
    f = rng.uniform(0, 1, (T, 52)).astype(np.float32) if face else np.zeros((T, 52), np.float32)
    return ClipArrays("synthetic", pose, pitch, f, _speech_like(T / 15 + 0.1, seed)[: T * SR // 15])


@pytest.mark.slow
def test_a_style_records_its_inputs_and_ignores_a_face_it_never_saw(tmp_path):
    from facecapges.styles import load_style
    from facecapges.training.train import build_trainer

    tr = build_trainer([_clip()], tmp_path / "run", dict(TINY), dict(epochs=1, batch_size=8, holdout_from=120,
                                                                      num_threads=1), {"speaker": 2}, resume=False)
    tr.fit(progress=False)
    ck = load_style(tmp_path / "run")
    assert ck.meta["inputs"]["face"] is False and ck.meta["inputs"]["audio"] == "raw"
    ref = np.asarray(ck.meta["head_reference_rot6d"])
    assert np.degrees(np.arccos(np.clip(ref[4], -1, 1))) == pytest.approx(np.degrees(0.23), abs=1.0)
    a, h = torch.randn(1, 30, SPF) * 0.1, torch.randn(1, 30, 6) * 0.1
    with torch.no_grad():  # any live face gives exactly what training gave: no face
        z0 = ck.model.encode(a, torch.zeros(1, 30, 52), h)
        z1 = ck.model.encode(a, torch.rand(1, 30, 52), h)
    assert torch.equal(z0, z1)
    # held-out frames never enter a statistic: the scale of the head comes from frames < 120 only
    tr2 = build_trainer([_clip(face=True)], tmp_path / "run2", dict(TINY), dict(epochs=1, batch_size=8,
                        holdout_from=120, num_threads=1), {"speaker": 2}, resume=False)
    assert tr2.inputs["face"] is True
    c = _clip(face=True)
    np.testing.assert_allclose(tr2.G.face_enc.inp.in_mean.numpy(), c.face[:120].mean(0), atol=1e-5)


@pytest.mark.slow
def test_offline_variant_resumes_through_the_one_trainer(tmp_path):
    """The offline decoder gets resume by construction: 2 + 1 epochs equal 3 in one go."""
    from facecapges.training.bidirectional import BIDIRECTIONAL
    from facecapges.training.train import build_trainer

    over = dict(epochs=3, batch_size=8, optimizer="adam", lr_base=0.016, adv_start_epoch=2, holdout_from=120,
                num_threads=1)
    one = build_trainer([_clip()], tmp_path / "one", dict(TINY), over, {}, resume=False, variant=BIDIRECTIONAL)
    one.fit(progress=False)
    two = build_trainer([_clip()], tmp_path / "two", dict(TINY), over, {}, resume=False, variant=BIDIRECTIONAL)
    two.fit(epochs=2, progress=False)
    again = build_trainer([_clip()], tmp_path / "two", {}, {"epochs": 3}, {}, resume=True, variant=BIDIRECTIONAL)
    again.fit(progress=False)
    # resumed against uninterrupted, one process, one thread, the state restored bit for bit: the same code path,
    # so bit for bit on any CPU (docs/testing.md; test_model_cli checks the same of the default variant)
    for k, v in one.G.state_dict().items():
        assert torch.equal(again.G.state_dict()[k], v), k
    assert [r["epoch"] for r in again.history] == [1, 2, 3]
    from facecapges.errors import UserError

    with pytest.raises(UserError, match="offline"):  # a closed-loop trainer refuses an offline run
        build_trainer([_clip()], tmp_path / "two", {}, {}, {}, resume=True)


# ------------------------------------------------------------- styles install
@pytest.mark.slow
def test_styles_install_puts_a_run_where_style_finds_it(tmp_path, monkeypatch):
    from facecapges.errors import UserError
    from facecapges.styles import install_style, list_styles, load_style, styles_dir, user_styles_dir
    from facecapges.training.train import build_trainer

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("FACECAPGES_STYLES", raising=False)
    assert user_styles_dir() == tmp_path / "xdg" / "facecapges" / "styles"
    run = tmp_path / "my-run"
    build_trainer([_clip()], run, dict(TINY), dict(epochs=1, batch_size=8, holdout_from=120, num_threads=1),
                  {"speaker": 7}, resume=False).fit(progress=False)
    (run / "model.fgd").mkdir()
    (run / "model.fgd" / "x.json").write_text("{}")
    shipped = sorted(p.name for p in styles_dir().iterdir())
    dest = install_style(run)
    assert dest == user_styles_dir() / "my-run.safetensors" and (user_styles_dir() / "my-run.log.csv").is_file()
    assert (user_styles_dir() / "my-run.fgd" / "x.json").is_file()
    assert list_styles()["my-run"] == dest and load_style(style="my-run").meta["speaker"] == 7
    assert sorted(p.name for p in styles_dir().iterdir()) == shipped  # the package is untouched
    with pytest.raises(UserError, match="--force"):
        install_style(run)
    install_style(run, force=True)
    with pytest.raises(UserError, match="name"):
        install_style(run, name="../escape")
    (tmp_path / "junk.safetensors").write_bytes(b"not a checkpoint")
    with pytest.raises(UserError):
        install_style(tmp_path / "junk.safetensors")


@pytest.mark.slow
def test_fine_tuning_starts_from_the_base_styles_weights_with_its_own_statistics(tmp_path):
    """``train.init_from``: the base's learned weights, this speaker's own input statistics."""
    from facecapges.errors import UserError
    from facecapges.training.train import build_trainer

    over = dict(epochs=1, batch_size=8, holdout_from=120, num_threads=1)
    base = build_trainer([_clip(seed=1)], tmp_path / "base", dict(TINY), over, {}, resume=False)
    base.fit(progress=False)
    ft = build_trainer([_clip(face=True)], tmp_path / "ft", dict(TINY), dict(over, init_from=str(tmp_path / "base")),
                       {}, resume=False)
    for k, v in base.G.state_dict().items():
        if k.endswith(("in_mean", "in_scale")):
            continue
        assert torch.equal(ft.G.state_dict()[k], v), k  # every learned weight, the output heads included
    c = _clip(face=True)  # … and the fine-tuned speaker's own statistics (the base had no face)
    np.testing.assert_allclose(ft.G.face_enc.inp.in_mean.numpy(), c.face[:120].mean(0), atol=1e-5)
    assert float(base.G.face_enc.inp.in_scale.abs().max()) == 0.0
    with pytest.raises(UserError, match=r"model\.lstm_hidden is 16, this run's is 24"):
        build_trainer([_clip()], tmp_path / "bad", dict(TINY, lstm_hidden=24),
                      dict(over, init_from=str(tmp_path / "base")), {}, resume=False)


def test_a_base_is_named_by_a_path_or_by_an_installed_style(tmp_path):
    from facecapges.errors import UserError
    from facecapges.styles import load_style_or_file

    assert load_style_or_file("beat2-scott-demo").path.name == "beat2-scott-demo.safetensors"
    with pytest.raises(UserError, match="checkpoint not found"):  # a path that is not there is not a style name
        load_style_or_file(str(tmp_path / "missing.safetensors"))
    with pytest.raises(UserError, match="unknown style 'no-such-style'"):
        load_style_or_file("no-such-style")


@pytest.mark.slow
def test_head_dropout_holds_whole_segments_still_facing_the_camera(tmp_path):
    """``train.head_dropout``: a segment's head input is held at the camera frame's identity, whole."""
    from facecapges.errors import UserError
    from facecapges.training.segments import hold_head_still
    from facecapges.training.train import build_trainer

    torch.manual_seed(0)
    head = torch.randn(400, 50, 6)
    before = head.clone()
    hold_head_still(head, 0.3)
    still = (head == torch.tensor(rot.identity_rot6d())).all(-1).all(-1)  # (400,)
    assert 0.2 < float(still.float().mean()) < 0.4
    assert torch.equal(head[~still], before[~still])  # the others untouched, whole segments only
    assert bool((head == torch.tensor(rot.identity_rot6d())).all(-1).any(-1).eq(still).all())
    over = dict(epochs=1, batch_size=8, holdout_from=120, num_threads=1)
    logs = []
    for p in (0.0, 1.0):
        tr = build_trainer([_clip()], tmp_path / f"run{p}", dict(TINY), dict(over, head_dropout=p), {}, resume=False)
        logs.append(tr.fit(progress=False)[-1]["rec"])
    assert logs[0] != logs[1]  # the setting reaches the training loop
    with pytest.raises(UserError, match="head_dropout"):
        build_trainer([_clip()], tmp_path / "bad", dict(TINY), dict(over, head_dropout=1.5), {}, resume=False)


@pytest.mark.slow
def test_amplitude_loss_asks_for_the_swing_not_its_timing(tmp_path):
    """``train.w_amp``: a stroke made a little off time costs nothing, holding still does."""
    from facecapges.training.masking import amplitude_loss, masked_reconstruction_losses
    from facecapges.training.train import build_trainer

    t = torch.arange(22, dtype=torch.float32)  # 22 frames: two 9-frame strokes in the 18 smoothed ones

    def stroke(shift: float) -> torch.Tensor:
        return torch.sin(2 * np.pi * (t - shift) / 9)[None, :, None].repeat(2, 1, 12) * 0.2

    real, late, still = stroke(0.0), stroke(2.0), torch.zeros(2, 22, 12)
    late_losses, still_losses = (masked_reconstruction_losses(g, real, 0.1) for g in (late, still))
    assert late_losses["rec"] > 0.5 * still_losses["rec"]  # the pose loss: a late stroke ~ no stroke
    assert float(late_losses["amp"]) < 0.05 * float(still_losses["amp"])
    jitter = real + 0.1 * (-1.0) ** t[None, :, None]  # the same swing bought with frame-to-frame jitter
    assert float(amplitude_loss(jitter, real)) > 0.02 + float(late_losses["amp"])
    x = still.clone().requires_grad_(True)
    amplitude_loss(x, real).backward()
    assert torch.isfinite(x.grad).all()  # finite at rest (the sd's epsilon)
    over = dict(epochs=1, batch_size=8, holdout_from=120, num_threads=1)
    logs = [build_trainer([_clip()], tmp_path / f"run{w}", dict(TINY), dict(over, w_amp=w), {}, resume=False)
            .fit(progress=False)[-1] for w in (0.0, 1000.0)]
    assert logs[0]["total"] != logs[1]["total"] and "held_amp" in logs[1]  # the setting reaches the loop
