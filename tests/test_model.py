"""The gesture model: causality, streaming == training rollout, checkpoints, training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from facecapges.errors import UserError
from facecapges.network.config import ModelConfig, TrainConfig
from facecapges.network.network import FaceCapGes
from facecapges.network.streaming import NaiveNetworkStream, NetworkStream
from facecapges.network.style import save_checkpoint
from facecapges.styles import load_style
from tolerances import NETWORK_ULPS, assert_float32_close, assert_rotations_close

SMALL = dict(audio_frontend_channels=(8, 8, 8), audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8,
             face_dim=8, lstm_hidden=16, mlp_hidden=16, disc_channels=8)


def _inputs(T: int, cfg: ModelConfig, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    audio = torch.randn(1, T, cfg.samples_per_frame, generator=g) * 0.1
    face = torch.rand(1, T, 52, generator=g)
    head = torch.randn(1, T, 6, generator=g)
    pose = torch.randn(1, T, cfg.pose_dim, generator=g) * 0.3
    return audio, face, head, pose


@pytest.fixture(scope="module")
def model() -> FaceCapGes:
    torch.manual_seed(0)
    return FaceCapGes(ModelConfig()).eval()


def test_receptive_field_is_the_window():
    cfg = ModelConfig()
    assert sum(cfg.audio_tcn_dilations) + 1 == cfg.window == 17
    assert sum(cfg.face_tcn_dilations) + 1 == cfg.window
    assert len(cfg.audio_tcn_dilations) == 12 and len(cfg.face_tcn_dilations) == 8
    with pytest.raises(UserError):
        ModelConfig(audio_tcn_dilations=(2,) * 12).validate()


def test_embedding_depends_only_on_its_own_window(model):
    """z_τ from the whole clip equals z_τ from inputs τ−N…τ alone (eq. 3.2)."""
    cfg = model.cfg
    a, f, h, _ = _inputs(60, cfg)
    with torch.no_grad():
        full = model.encode(a, f, h)
        t = 40
        win = model.encode(a[:, t - cfg.n_history:t + 1], f[:, t - cfg.n_history:t + 1], h[:, t - cfg.n_history:t + 1])
    # convolutions over 60 frames against 17 (oneDNN may pick another algorithm): float32 rounding of the embedding
    assert_float32_close(win[0, -1], full[0, t], float(full.abs().max()), NETWORK_ULPS, "embedding units")


def test_future_inputs_do_not_change_past_outputs(model):
    """Strict causality: perturbing every input after t0 leaves outputs ≤ t0 bit-identical."""
    cfg, N, T, t0 = model.cfg, model.cfg.n_history, 70, 45
    a, f, h, p = _inputs(T, cfg)
    a2, f2, h2 = a.clone(), f.clone(), h.clone()
    a2[:, t0 + 1:] += 5.0
    f2[:, t0 + 1:] = 1.0 - f2[:, t0 + 1:]
    h2[:, t0 + 1:] *= -3.0
    with torch.no_grad():
        out1 = model.rollout(model.encode(a, f, h), p[:, :N])
        out2 = model.rollout(model.encode(a2, f2, h2), p[:, :N])
    k = t0 - N + 1  # generated frames N … t0
    assert torch.equal(out1[:, :k], out2[:, :k])
    assert not torch.equal(out1[:, k:], out2[:, k:])  # the perturbation does reach the future


def test_streaming_causality(model):
    cfg, T, t0 = model.cfg, 50, 30
    a, f, h, _ = _inputs(T, cfg)
    outs = []
    for scale in (1.0, 4.0):
        g = NetworkStream(model, np.zeros((cfg.n_history, 47, 6), np.float32))
        seq = []
        for t in range(T):
            k = scale if t > t0 else 1.0
            seq.append(g.step(a[0, t].numpy() * k, f[0, t].numpy(), h[0, t].numpy() * k))
        outs.append(np.stack(seq))
    assert np.array_equal(outs[0][:t0 + 1], outs[1][:t0 + 1])
    assert not np.array_equal(outs[0][t0 + 1:], outs[1][t0 + 1:])


@pytest.mark.parametrize("cls", [NetworkStream, NaiveNetworkStream])
def test_streaming_equals_training_rollout(model, cls):
    cfg, N, T = model.cfg, model.cfg.n_history, 64
    a, f, h, p = _inputs(T, cfg, seed=3)
    with torch.no_grad():
        ref = model.rollout(model.encode(a, f, h), p[:, :N])[0].numpy()
    g = cls(model, np.zeros((N, 47, 6), np.float32))
    for t in range(N):
        g.warmup(a[0, t].numpy(), f[0, t].numpy(), h[0, t].numpy(), p[0, t].numpy())
    out = np.stack([g.step(a[0, t].numpy(), f[0, t].numpy(), h[0, t].numpy()) for t in range(N, T)])
    # one frame at a time against the whole clip (another batch, other kernels): float32 rounding, 0.01° (tolerances.py)
    assert_rotations_close(out, ref.reshape(out.shape), what=f"{cls.__name__} against the rollout")


def test_cold_start_fast_and_naive_agree(model):
    cfg, T = model.cfg, 40
    a, f, h, _ = _inputs(T, cfg, seed=5)
    neutral = np.random.default_rng(0).normal(size=(cfg.n_history, 47, 6)).astype(np.float32)
    fast, naive = NetworkStream(model, neutral), NaiveNetworkStream(model, neutral)
    for t in range(T):
        x = (a[0, t].numpy(), f[0, t].numpy(), h[0, t].numpy())
        # the cached kernel against the naive loop: float32 rounding, 0.01° (tolerances.py)
        assert_rotations_close(fast.step(*x), naive.step(*x), what=f"frame {t}")


def test_rollout_batch_equals_single_clips(model):
    cfg, N, T = model.cfg, model.cfg.n_history, 34
    batches = [_inputs(T, cfg, seed=s) for s in range(3)]
    cat = [torch.cat([b[i] for b in batches]) for i in range(4)]
    with torch.no_grad():
        together = model.rollout(model.encode(*cat[:3]), cat[3][:, :N])
        for i, b in enumerate(batches):
            alone = model.rollout(model.encode(*b[:3]), b[3][:, :N])
            # a batch of 3 against 1 (another GEMM blocking): float32 rounding, 0.01° (tolerances.py)
            assert_rotations_close(together[i].reshape(-1, 47, 6), alone[0].reshape(-1, 47, 6), what=f"clip {i}")


def test_streaming_rejects_bad_frames(model):
    g = NetworkStream(model, np.zeros((16, 47, 6), np.float32))
    with pytest.raises(ValueError):
        g.step(np.zeros(5000), np.zeros(52), np.zeros(6))
    with pytest.raises(ValueError):
        g.step(np.zeros(1067), np.zeros(51), np.zeros(6))
    out = g.step(np.full(1067, np.nan), np.full(52, np.nan), np.zeros(6))  # NaN input never gives NaN output
    assert np.isfinite(out).all()


def test_checkpoint_round_trip_and_errors(tmp_path, model):
    meta = {"neutral_window": np.zeros((16, 47, 6)).tolist(), "speaker": 2,
            "skeleton": {"names": ["Hips"], "parents": [-1], "offsets": [[0, 0, 0]], "channels": [[]]}}
    path = save_checkpoint(tmp_path / "m.safetensors", model, meta)
    ck = load_style(path)
    for (k, v), (k2, v2) in zip(model.state_dict().items(), ck.model.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    assert ck.model.cfg == model.cfg
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a checkpoint at all")
    with pytest.raises(UserError, match=r"bad\.safetensors"):
        load_style(bad)
    # weights from another config
    other = FaceCapGes(ModelConfig(**SMALL))
    p2 = save_checkpoint(tmp_path / "o.safetensors", other, meta)
    import json

    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(p2), "pt") as f:
        md = json.loads(f.metadata()["facecapges"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 — a safetensors handle, not a dict
    md["model_config"] = json.loads(json.dumps(__import__("dataclasses").asdict(ModelConfig())))
    save_file(tensors, str(tmp_path / "mixed.safetensors"), metadata={"facecapges": json.dumps(md)})
    with pytest.raises(UserError, match="do not match"):
        load_style(tmp_path / "mixed.safetensors")


def test_train_config_learning_rates():
    t = TrainConfig()
    lr_g, lr_d = t.learning_rates()
    assert lr_g == pytest.approx(2.5e-4 * 256 / 128)
    assert lr_d == pytest.approx(0.2 * lr_g)
    assert t.learning_rates(world_size=4)[0] == pytest.approx(4 * lr_g)  # linear in the global batch
    assert (t.clip_len, t.stride, t.huber_beta, t.epochs, t.adv_start_epoch) == (34, 10, 0.1, 375, 11)
    assert (t.w_rec, t.w_vel, t.w_acc, t.w_adv) == (500, 1000, 1000, 0.1)
