"""The CaMN baseline: shapes, bidirectionality, the seed/mask input, trainer variant, checkpoint round trip."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from facecapges.errors import UserError
from facecapges.evaluation.camn import CaMN, CaMNConfig, build_camn_trainer, camn_batch, load_camn, save_camn
from facecapges.network.config import ModelConfig
from facecapges.network.network import set_input_statistics

SMALL = CaMNConfig(hidden=32, layers=2, audio_f=16, facial_f=8, head_f=4)


def _inputs(T, cfg, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(1, T, cfg.samples_per_frame, generator=g) * 0.1, torch.rand(1, T, cfg.n_face, generator=g),
            torch.randn(1, T, 6, generator=g))


def test_paper_sizes():
    m = CaMN(ModelConfig())
    assert m.lstm_body.bidirectional and m.lstm_body.num_layers == 4 and m.lstm_body.hidden_size == 256
    assert m.lstm_hands.input_size == m.lstm_body.input_size + 3 * 6  # hands see the body output (cascade)
    assert 10e6 < sum(p.numel() for p in m.parameters()) < 20e6


def test_bidirectional_whole_segment_decoding():
    cfg = ModelConfig()
    torch.manual_seed(0)
    m = CaMN(cfg, SMALL).eval()
    a, f, h = _inputs(40, cfg)
    seed = torch.randn(1, 16, cfg.pose_dim)
    with torch.no_grad():
        out = m(a, f, h, seed)
        a2 = a.clone()
        a2[:, 35:] = torch.randn_like(a2[:, 35:])  # change only the future
        out2 = m(a2, f, h, seed)
        seed2 = seed.clone()
        seed2[:, 15] += 1.0
        out3 = m(a, f, h, seed2)
    assert out.shape == (1, 40, cfg.pose_dim)
    assert (out2[:, :30] - out[:, :30]).abs().max() > 1e-6  # frame 10 depends on frames after it: offline
    assert (out3[:, 16:20] - out[:, 16:20]).abs().max() > 1e-5  # the seed poses reach the generated frames


def test_face_scale_zero_removes_the_face():
    cfg = ModelConfig()
    torch.manual_seed(0)
    m = CaMN(cfg, SMALL).eval()
    set_input_statistics(m, {"face": (np.zeros(cfg.n_face), np.zeros(cfg.n_face))})
    a, f, h = _inputs(20, cfg)
    seed = torch.zeros(1, 16, cfg.pose_dim)
    with torch.no_grad():
        assert torch.equal(m(a, f, h, seed), m(a, torch.rand_like(f), h, seed))
    assert "audio" in m.input_norm_layers()
    assert "audio" not in CaMN(ModelConfig(audio_repr="mel"), SMALL).input_norm_layers()


def test_generate_places_the_seed_before_the_sequence():
    cfg = ModelConfig()
    m = CaMN(cfg, SMALL)
    T = 25
    out = m.generate(np.zeros((T, cfg.samples_per_frame)), np.zeros((T, 52)), np.zeros((T, 6)),
                     np.zeros((16, 47, 6)))
    assert out.shape == (T, 47, 6) and np.isfinite(out).all()
    with pytest.raises(ValueError):
        m.generate(np.zeros((T, cfg.samples_per_frame)), np.zeros((T, 52)), np.zeros((T, 6)), np.zeros((16, 40, 6)))


def _clips(n=2, T=160):
    from facecapges.training.segments import ClipArrays

    rng = np.random.default_rng(0)
    from facecapges import rotations as rot

    out = []
    for i in range(n):
        pose = rot.normalize_rot6d(rot.identity_rot6d((T, 47)) + 0.1 * rng.normal(size=(T, 47, 6))).astype(np.float32)
        out.append(ClipArrays(f"c{i}", pose, rot.identity_rot6d((T,)).astype(np.float32),
                              np.zeros((T, 52), np.float32), (0.1 * rng.normal(size=T * 16000 // 15)).astype(np.float32)))
    return out


@pytest.mark.slow
def test_trained_by_the_one_trainer_and_round_trips(tmp_path, monkeypatch):
    import facecapges.evaluation.camn as camn_mod

    monkeypatch.setattr(camn_mod, "build_camn", lambda cfg: CaMN(cfg, SMALL))  # small sizes for a quick run
    tr = build_camn_trainer(_clips(), tmp_path / "run", {}, dict(batch_size=8, optimizer="adam", lr_base=0.008,
                                                                 epochs=2, holdout_from=110, num_threads=1), {"x": 1})
    hist = tr.fit(progress=False)
    assert len(hist) == 2 and np.isfinite(hist[-1]["rec"]) and "held_rec" in hist[-1]
    model, meta = load_camn(tmp_path / "run" / "model.safetensors")
    assert meta["variant"] == "CaMN" and meta["camn_config"]["hidden"] == 32 and meta["x"] == 1
    assert meta["inputs"]["face"] is False
    assert torch.count_nonzero(model.face_norm.in_scale) == 0  # never saw a face: the face cannot reach it
    batch = tr.train_set.gather(np.arange(4))
    with torch.no_grad():
        tr.G.eval()
        a, _ = camn_batch(tr.G, batch)
        b, _ = camn_batch(model, batch)
    torch.testing.assert_close(a, b)


def test_load_refuses_other_files(tmp_path):
    from facecapges.network.network import FaceCapGes
    from facecapges.network.style import save_checkpoint

    p = save_checkpoint(tmp_path / "fcg.safetensors", FaceCapGes(ModelConfig()), {})
    with pytest.raises(UserError, match="not a CaMN checkpoint"):
        load_camn(p)
    (tmp_path / "junk.safetensors").write_bytes(b"nope")
    with pytest.raises(UserError):
        load_camn(tmp_path / "junk.safetensors")
    m = CaMN(ModelConfig(), SMALL)
    q = save_camn(tmp_path / "c.safetensors", m, {"neutral_window": []})
    assert load_camn(q)[0].camn == SMALL
