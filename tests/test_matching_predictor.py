"""The motion-matching engine's speech predictor (matching/predictor.py, trained by predictor_training.py): causal, one kernel, trainable."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from conftest import shared_file
from facecapges import rotations as rot
from facecapges import timing
from facecapges.matching.predictor import (
    OUTPUT_NAMES,
    K,
    Predictor,
    PredictorSettings,
)
from facecapges.matching.predictor_training import evaluate_predictor, predict, take_targets, train_predictor
from facecapges.matching.takes import load_take, make_take, mirror_take
from facecapges.matching.targets import TARGET_NAMES
from tolerances import NETWORK_ULPS, assert_float32_close

TINY = PredictorSettings(
    audio_tcn_channels=16,
    audio_dim=16,
    face_tcn_channels=8,
    face_dim=4,
    head_dim=4,
    hidden=16,
    batch=16,
    segment=40,
    steps=150,
    lr=3e-3,
    eval_every=25,
    patience=3,
)
SPF = timing.samples_per_frame()


@pytest.fixture(scope="module")
def beat_take(beat_bvh, beat_wav):
    return load_take(beat_bvh, beat_wav)


@pytest.fixture(scope="module")
def zeggs_take(beat_bvh):
    from facecapges.io.bvh import read_bvh

    bvh, wav = shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"), shared_file("data/zeggs/067_Speech_2_x_1_0.wav")
    return load_take(bvh, wav, read_bvh(beat_bvh).skeleton)


@pytest.fixture(scope="module")
def quick(beat_take):
    """An untrained-quality predictor on a 20 s slice of the BEAT take (a few steps), with a face seen."""
    T = 300
    rng = np.random.default_rng(1)
    face = np.clip(rng.normal(0.2, 0.1, (T, 52)), 0, 1).astype(np.float32)
    take = make_take("slice", beat_take.pose[:T], beat_take.audio, beat_take.skeleton, face=face)
    return train_predictor([take], seed=3, progress=False, settings=replace(TINY, steps=10, eval_every=5))


def _inputs(T: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    audio = (rng.normal(0, 0.1, (T, SPF)) * rng.random((T, 1))).astype(np.float32)
    face = rng.random((T, 52)).astype(np.float32)
    angles = rng.normal(0, 0.2, (T, 3))
    head = rot.euler_to_rot6d(angles, "XYZ").astype(np.float32)
    return audio, face, head


def _scale(out: np.ndarray) -> np.ndarray:
    """Each output column's magnitude (cm/s, cm, probability), at least 1 of its unit: what its float32 rounding
    is relative to."""
    return np.maximum(np.abs(out).reshape(-1, out.shape[-1]).max(0), 1.0)


def test_stream_is_strictly_causal_and_equals_the_network(quick, beat_take):
    T, cut = 40, 25
    _, face, head = _inputs(T, 0)
    audio = timing.frame_audio(beat_take.audio[200 * SPF :], T)  # speech: noise puts F0 candidates at near ties
    audio2, face2, head2 = audio.copy(), face.copy(), head.copy()
    audio2[cut:] = np.random.default_rng(9).normal(0, 0.3, audio2[cut:].shape)
    face2[cut:] = 1.0 - face2[cut:]
    head2[cut:] = rot.identity_rot6d()
    runs = []
    for a, f, h in ((audio, face, head), (audio2, face2, head2)):
        s = quick.stream()
        runs.append(np.stack([s.step(a[i], f[i], h[i]) for i in range(T)]))
    assert runs[0].shape == (T, K + 1) and runs[0].dtype == np.float32
    np.testing.assert_array_equal(runs[0][:cut], runs[1][:cut])  # the future changed nothing before it
    assert np.abs(runs[0][cut:] - runs[1][cut:]).max() > 1e-4  # … and is read from then on
    samples = np.concatenate([a[: e - s] for a, s, e in zip(audio, *timing.frame_sample_bounds(np.arange(T)))])
    offline = predict(quick, samples, face, head)  # the network over the whole sequence
    # frame by frame against the whole sequence (other kernels): float32 rounding of the network's outputs
    # (cm/s, cm, speaking probability), NETWORK_ULPS of each column's scale (tolerances.py)
    assert_float32_close(runs[0], offline, _scale(offline), NETWORK_ULPS, "cm, cm/s or 1", "stream against offline")
    assert ((runs[0][:, K] >= 0) & (runs[0][:, K] <= 1)).all()


def test_stream_reset_starts_over(quick):
    audio, face, head = _inputs(20, 1)
    s = quick.stream()
    first = np.stack([s.step(audio[i], face[i], head[i]) for i in range(20)])
    s.reset()
    again = np.stack([s.step(audio[i], face[i], head[i]) for i in range(20)])
    np.testing.assert_array_equal(first, again)  # the same stream, the same code path: bit for bit


def test_batched_equals_one_stream_per_slot(quick):
    T = 30
    inputs = [_inputs(T, 10 + k) for k in range(3)]
    alone = []
    for a, f, h in inputs:
        s = quick.stream()
        alone.append(np.stack([s.step(a[i], f[i], h[i]) for i in range(T)]))
    bp = quick.batched(1)  # grows as slots open
    slots = [bp.open() for _ in range(3)]
    got = np.zeros((3, T, K + 1), np.float32)
    for i in range(T):
        order = [2, 0, 1] if i % 2 else [0, 1, 2]  # the slots' order in a step does not matter
        out = bp.step(
            [slots[k] for k in order],
            np.stack([inputs[k][0][i] for k in order]),
            np.stack([inputs[k][1][i] for k in order]),
            np.stack([inputs[k][2][i] for k in order]),
        )
        for row, k in enumerate(order):
            got[k, i] = out[row]
    for k in range(3):  # a batch of 3 against one stream: float32 rounding, NETWORK_ULPS of each column's scale
        assert_float32_close(got[k], alone[k], _scale(alone[k]), NETWORK_ULPS, "cm, cm/s or 1", f"slot {k}")
    with pytest.raises(AssertionError, match="differ by more than"):  # a wrong slot would be seen
        assert_float32_close(got[0], alone[1], _scale(alone[1]), NETWORK_ULPS, "cm, cm/s or 1")
    bp.close(slots[1])
    with pytest.raises(KeyError):
        bp.step([slots[1]], inputs[1][0][:1], inputs[1][1][:1], inputs[1][2][:1])
    reopened = bp.open()
    a, f, h = inputs[0]
    assert_float32_close(bp.step([reopened], a[:1], f[:1], h[:1])[0], alone[0][0], _scale(alone[0]), NETWORK_ULPS,
                         "cm, cm/s or 1", "a reopened slot")  # a fresh state, as a new stream's


def test_state_round_trip_through_json(quick, tmp_path):
    from safetensors.numpy import load_file, save_file

    config = json.loads(json.dumps(quick.config))
    save_file(quick.state_dict(), tmp_path / "p.safetensors")
    again = Predictor.from_state(config, load_file(tmp_path / "p.safetensors"))
    assert config["outputs"] == list(OUTPUT_NAMES) and len(config["target_mean"]) == len(TARGET_NAMES)
    audio, face, head = _inputs(20, 5)
    s1, s2 = quick.stream(), again.stream()
    for i in range(20):
        np.testing.assert_array_equal(s1.step(audio[i], face[i], head[i]), s2.step(audio[i], face[i], head[i]))
    with pytest.raises(ValueError):
        Predictor.from_state({**config, "format": "something else"}, quick.state_dict())


def test_numpy_kernel_equals_the_torch_network_for_both_front_ends(beat_take):
    """The run-time kernel (NumPy) against the training side's torch forward over the whole sequence, with
    random weights of both audio representations (Mel and raw samples) and a face and head that move."""
    from facecapges.matching.predictor_training import SpeechReader, audio_frames

    T = 40
    _, face, head = _inputs(T, 4)
    audio = beat_take.audio[100 * SPF : 100 * SPF + int(timing.frame_sample_bounds(T)[0])]
    for repr_ in ("mel", "raw"):
        settings = replace(TINY, audio_repr=repr_)
        cfg = settings.model_config()
        torch.manual_seed(0)
        net = SpeechReader(cfg, settings.hidden).eval()
        with torch.no_grad():  # non-trivial standardisation, as a trained reader has
            for mod in net.modules():
                if hasattr(mod, "in_scale"):
                    mod.in_mean.uniform_(-0.2, 0.2)
                    mod.in_scale.uniform_(0.5, 2.0)
            a = torch.from_numpy(audio_frames(audio, T, cfg))[None]
            want = net(a, torch.from_numpy(face)[None], torch.from_numpy(head)[None])[0].numpy()
        config = {"format": "facecapges-speech-predictor", "version": 1, "settings": {"hidden": settings.hidden},
                  "model": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.__dict__.items()},
                  "target_mean": [0.0] * K, "target_sd": [1.0] * K, "head_reference": [1, 0, 0, 0, 1, 0]}
        pred = Predictor.from_state(config, {k: v.numpy() for k, v in net.state_dict().items()})
        s = pred.stream()
        got = np.stack([s.step(audio[a0:a1], face[i], head[i])
                        for i, (a0, a1) in enumerate(zip(*timing.frame_sample_bounds(np.arange(T))))])
        want = pred.outputs(want)
        assert_float32_close(got, want, _scale(want), NETWORK_ULPS, "cm, cm/s or 1", f"{repr_}: NumPy against torch")
        with pytest.raises(AssertionError, match="differ by more than"):  # a frame late would be seen
            assert_float32_close(got[1:], want[:-1], _scale(want), NETWORK_ULPS, "cm, cm/s or 1")
    with pytest.raises(ValueError, match="expected"):  # weights of another size: a clear error, not a crash later
        Predictor.from_state(config, {**pred.state_dict(), "out.4.bias": np.zeros(3, np.float32)})


def test_a_matching_style_runs_without_torch():
    """``live`` / ``serve`` with a matching style: loading it and stepping a stream (predictor included) does not
    import torch (issue 36: ~85 MB of libraries a matching style does not need); the compiled kernels' Numba it
    does (docs/performance.md, "Engine step, third pass")."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from facecapges.styles import load_style\n"
        "st = load_style(style='beat2-scott-mm')\n"
        "assert st.predictor is not None\n"
        "g = st.streaming()\n"
        "for i in range(20):\n"
        "    g.step(np.random.default_rng(i).normal(0, 0.1, 1067).astype(np.float32), np.zeros(52, np.float32),"
        " np.array([1, 0, 0, 0, 1, 0], np.float32))\n"
        "print(sorted(m for m in ('torch', 'torchaudio') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout


def test_training_reads_no_held_out_frame(beat_take):
    """Whatever the held-out frames hold, the trained predictor is the same."""
    T = 240
    take = make_take("a", beat_take.pose[:T], beat_take.audio, beat_take.skeleton)
    other = replace(
        take,
        pose=take.pose.copy(),
        audio=take.audio.copy(),
        head=take.head.copy(),
        face=take.face.copy(),
    )
    cut, s0 = take.train_until, int(timing.frame_sample_bounds(take.train_until)[0])
    other.pose[cut:] = other.pose[::-1][: T - cut]
    other.audio[s0:] = np.random.default_rng(0).normal(0, 0.5, len(other.audio) - s0)
    other.head[cut:] = rot.identity_rot6d()
    other.face[cut:] = 0.7
    settings = replace(TINY, steps=6, eval_every=3)
    a = train_predictor([take], seed=0, progress=False, settings=settings)
    b = train_predictor([other], seed=0, progress=False, settings=settings)
    for k, v in a.state_dict().items():
        np.testing.assert_array_equal(v, b.state_dict()[k])  # the same training run: the same bits
    assert a.config["target_mean"] == b.config["target_mean"]
    # and the validation targets come from the motion before train_until only
    np.testing.assert_array_equal(take_targets(take, cut), take_targets(other, cut))


def test_trained_predictor_beats_the_mean_on_zeggs_validation(zeggs_take):
    """ZEGGS (retargeted at run time, nothing written): the wrist-speed targets with the head held still."""
    pred = train_predictor([zeggs_take, mirror_take(zeggs_take)], seed=0, progress=False, settings=TINY)
    figures = evaluate_predictor(pred, [zeggs_take], "validation")["head_still"]
    for name in ("wrist_speed_0.3s", "wrist_speed_0.6s"):
        f = figures["targets"][name]
        # five seeds gave r 0.45–0.59, R² 0.19–0.32; untrained (one step): R² −0.06 … 0.00
        assert f["r"] > 0.35, (name, f)
        assert f["r2_vs_training_mean"] > 0.1, (name, f)
    assert figures["speaking_auc"] > 0.9
