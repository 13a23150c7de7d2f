"""BatchedNetworkStreams: every stream's output equals the naive re-windowed loop and a
one-slot NetworkStream to float32 rounding (0.01° per joint, tests/tolerances.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from facecapges.network.batched import BatchedNetworkStreams, pack_audio
from facecapges.network.config import ModelConfig
from facecapges.network.network import FaceCapGes
from facecapges.network.streaming import NaiveNetworkStream, NetworkStream
from tolerances import assert_rotations_close

SMALL = dict(audio_frontend_channels=(8, 8, 8), audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8,
             face_dim=8, lstm_hidden=16, mlp_hidden=16)


def _model(**over) -> FaceCapGes:
    torch.manual_seed(0)
    m = FaceCapGes(ModelConfig(**over)).eval()
    with torch.no_grad():  # non-trivial LSTM states and heads: scale the random weights up a little
        for p in m.decoder.parameters():
            p.mul_(2.0)
    return m


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """One intra-op thread: on a loaded 2-core machine two OpenMP threads spin-wait for each other."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _streams(S: int, T: int, cfg: ModelConfig, seed: int = 0):
    rng = np.random.default_rng(seed)
    spf = cfg.samples_per_frame
    audio = [[(rng.normal(size=int(rng.integers(spf - 1, spf + 1))) * 0.2).astype(np.float32) for _ in range(T)]
             for _ in range(S)]
    face = rng.uniform(size=(S, T, 52)).astype(np.float32)
    head = rng.normal(size=(S, T, 6)).astype(np.float32)
    return audio, face, head


def _neutral(cfg: ModelConfig, seed: int = 1) -> np.ndarray:
    return (np.random.default_rng(seed).normal(size=(cfg.n_history, cfg.n_joints, 6)) * 0.3).astype(np.float32)


@pytest.mark.parametrize(("layers", "audio_repr"), [(1, "raw"), (1, "mel"), (2, "raw")])
def test_each_stream_equals_the_naive_loop(layers, audio_repr):
    """Streams join late, skip ticks, leave and are replaced; outputs match the oracle and a
    one-slot NetworkStream to float32 rounding: 0.01° on every joint of every frame.

    One-layer decoders run the cached kernel (the served path, on the default config) in
    both its schedules: native loops for small batches and torch for large ones (a second
    generator with the native ones turned off takes the same frames); two-layer decoders
    the model's own step (on a small config).
    """
    model = _model(audio_repr=audio_repr) if layers == 1 else _model(lstm_layers=layers, **SMALL)
    cfg, S, T = model.cfg, 6, 45
    neutral = _neutral(cfg)
    audio, face, head = _streams(S, T, cfg)
    init = (np.random.default_rng(5).normal(size=(cfg.n_joints, 6)) * 0.2).astype(np.float32)
    bg = BatchedNetworkStreams(model, neutral, capacity=2)  # grows while streams join
    assert bg.fast == (layers == 1)
    bt = BatchedNetworkStreams(model, neutral, capacity=2)  # the same, torch schedules only
    if bt.fast:
        bt.torch_schedules_only()
    slots: dict[int, int] = {}
    got: dict[int, list] = {s: [] for s in range(S)}
    got_torch: dict[int, list] = {s: [] for s in range(S)}
    due: dict[int, list] = {s: [] for s in range(S)}
    for t in range(T):
        for s in range(S - 1):
            if t == 3 * s:  # stream s joins at tick 3s
                slots[s] = bg.open(init if s == 2 else None)
                assert bt.open(init if s == 2 else None) == slots[s]
        if t == 30:  # stream 1 leaves; stream 5 joins next tick and takes over its slot
            left = slots.pop(1)
            bg.close(left)
            bt.close(left)
        if t == 31:
            slots[S - 1] = bg.open()
            assert slots[S - 1] == left == bt.open()
        active = [s for s in sorted(slots) if (t + s) % 4 != 0]  # every stream skips some ticks
        if not active:
            continue
        order = active[::-1] if t % 2 else active  # batch order does not matter
        args = ([slots[s] for s in order], [audio[s][t] for s in order], face[order, t], head[order, t])
        poses, poses_torch = bg.step(*args), bt.step(*args)
        for j, s in enumerate(order):
            got[s].append(poses[j])
            got_torch[s].append(poses_torch[j])
            due[s].append(t)
    assert bg.capacity >= 5
    for s in range(S):
        oracle, one = NaiveNetworkStream(model, neutral), NetworkStream(model, neutral)
        oracle.reset(init if s == 2 else None)
        one.reset(init if s == 2 else None)
        ref = np.array([oracle.step(audio[s][t], face[s, t], head[s, t]) for t in due[s]])
        alone = np.array([one.step(audio[s][t], face[s, t], head[s, t]) for t in due[s]])
        assert len(ref) > 5
        # other batches, other schedules (native / torch / the naive re-windowed loop; batched FFTs of the
        # Mel features): float32 rounding, which depends on the CPU's kernels; 0.01° (tolerances.py)
        assert_rotations_close(np.array(got[s]), ref, what=f"stream {s} against the naive loop")
        assert_rotations_close(np.array(got_torch[s]), ref, what=f"stream {s}, torch schedules, against the naive loop")
        assert_rotations_close(np.array(got[s]), alone, what=f"stream {s} against one slot alone")
    with pytest.raises(AssertionError, match="differ by more than"):  # a wrong slot would be seen
        assert_rotations_close(np.array(got[3][:5]), np.array(got[4][:5]))


def test_warmup_and_reset_match_single_stream():
    model = _model()
    cfg = model.cfg
    neutral = _neutral(cfg)
    audio, face, head = _streams(2, 30, cfg, seed=3)
    pose = (np.random.default_rng(2).normal(size=(30, cfg.n_joints, 6)) * 0.3).astype(np.float32)
    bg = BatchedNetworkStreams(model, neutral)
    a, b = bg.open(), bg.open()
    ga, gb = NaiveNetworkStream(model, neutral), NaiveNetworkStream(model, neutral)
    # the batched kernel against the naive loop: float32 rounding, 0.01° per joint (tolerances.py)
    for t in range(10):  # stream a warms up on known poses, b generates
        bg.warmup([a], [audio[0][t]], face[0, t:t + 1], head[0, t:t + 1], pose[t:t + 1])
        ga.warmup(audio[0][t], face[0, t], head[0, t], pose[t])
        out = bg.step([b], [audio[1][t]], face[1, t:t + 1], head[1, t:t + 1])
        assert_rotations_close(out[0], gb.step(audio[1][t], face[1, t], head[1, t]))
    for t in range(10, 20):
        out = bg.step([a, b], [audio[0][t], audio[1][t]], face[:, t], head[:, t])
        assert_rotations_close(out[0], ga.step(audio[0][t], face[0, t], head[0, t]))
        assert_rotations_close(out[1], gb.step(audio[1][t], face[1, t], head[1, t]))
    bg.reset(b)  # a reset stream starts over; the other keeps its state
    gb.reset()
    for t in range(20, 30):
        out = bg.step([b, a], [audio[1][t], audio[0][t]], face[::-1, t], head[::-1, t])
        assert_rotations_close(out[0], gb.step(audio[1][t], face[1, t], head[1, t]))
        assert_rotations_close(out[1], ga.step(audio[0][t], face[0, t], head[0, t]))


def test_bad_calls():
    model = _model()
    bg = BatchedNetworkStreams(model, _neutral(model.cfg))
    s = bg.open()
    spf = model.cfg.samples_per_frame
    with pytest.raises(KeyError):
        bg.step([s + 1], [np.zeros(spf)], np.zeros((1, 52)), np.zeros((1, 6)))
    with pytest.raises(ValueError, match="one frame"):
        bg.step([s, s], [np.zeros(spf)] * 2, np.zeros((2, 52)), np.zeros((2, 6)))
    with pytest.raises(ValueError, match="at most"):
        bg.step([s], [np.zeros(spf + 1)], np.zeros((1, 52)), np.zeros((1, 6)))
    with pytest.raises(ValueError, match="face"):
        bg.step([s], [np.zeros(spf)], np.zeros((1, 51)), np.zeros((1, 6)))
    with pytest.raises(ValueError, match="neutral window"):
        BatchedNetworkStreams(model, np.zeros((3, 47, 6)))
    # NaN inputs are cleaned as the single-stream generator does; output stays finite
    out = bg.step([s], [np.full(spf, np.nan, np.float32)], np.full((1, 52), np.nan), np.zeros((1, 6)))
    assert np.isfinite(out).all()
    bg.close(s)
    assert bg.n_open == 0 and bg.open() == s  # the slot is reused
    assert pack_audio([np.ones(3)], 5).tolist() == [[1, 1, 1, 0, 0]]
