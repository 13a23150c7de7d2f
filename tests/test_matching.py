"""The motion-matching engine: causal, blended, idle at intensity 0, one kernel for one and many streams,
its style file, and `styles build` end to end (a ZEGGS piece built from ../shared into tmp_path, never committed)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from conftest import shared_file
from facecapges import timing
from facecapges.engine.contract import GestureEngine
from facecapges.engine.generate import generate_poses
from facecapges.engine.inputs import FrameInputs
from facecapges.matching import inertialize as inz
from facecapges.matching.database import build_database, idle_rows, quaternions
from facecapges.matching.features import GROUP_NAMES, N_FEATURES, LiveFrames, group_slices, live_query
from facecapges.matching.matcher import BatchedMatchingStreams, MatchingConfig, MatchingStream, gain_of
from facecapges.matching.predictor import PredictorSettings
from facecapges.matching.predictor_training import train_predictor
from facecapges.matching.speech import SpeechTracker
from facecapges.matching.style import save_matching_style
from facecapges.matching.takes import load_take
from facecapges.styles import DEFAULT_NETWORK_STYLE, load_style
from runtime_helpers import cli, refused
from tolerances import assert_rotations_close

SPF = timing.samples_per_frame()
FPS = timing.MODEL_FPS
TINY = PredictorSettings(
    audio_tcn_channels=8, audio_dim=8, face_tcn_channels=4, face_dim=4, head_dim=4, hidden=8, batch=8, segment=40
)


@pytest.fixture(scope="session")
def take():
    return load_take(shared_file("data/beat/2_scott_0_1_1.bvh"), shared_file("data/beat/2_scott_0_1_1.wav"))


@pytest.fixture(scope="session")
def db(take):
    return build_database([take], [(0, 450)])


@pytest.fixture(scope="session")
def predictor(take):
    short = replace(take, train_until=450)  # what the database holds: nothing after it is read
    return train_predictor([short], seed=0, progress=False, settings=replace(TINY, steps=20, eval_every=10))


def run(gen, take, a: int, b: int, audio=None) -> np.ndarray:
    audio = take.audio if audio is None else audio
    return np.stack([gen.step(audio[t * SPF : (t + 1) * SPF], take.face[t], take.head[t]) for t in range(a, b)])


def accelerations(pose: np.ndarray) -> np.ndarray:
    """Joint angular accelerations (T-2, 47) rad/s² of rot6d poses."""
    v = inz.angular_velocity(quaternions(pose), FPS)[:-1]
    return np.linalg.norm(np.diff(v, axis=0), axis=-1) * FPS


def test_database_keeps_to_the_training_range_and_annotates(take, db):
    assert len(db) == 2 * 450  # the range and its mirror image, nothing past frame 450
    assert np.array_equal(db.pose[:450], take.pose[:450])
    assert not db.searchable[440:450].any() and db.searchable[:440].all()
    assert set(np.unique(db.phase)) <= set(range(5)) and len(np.unique(db.phase)) >= 4
    assert db.pause.any() and (~db.pause).any()
    idle = idle_rows(db)
    assert 0.2 <= idle.mean() < 0.9


def test_each_feature_group_fills_the_query_as_it_fills_the_database(take, db):
    """Given a database frame's own live inputs (the streaming speech cues of its audio, a predictor that
    estimates its own future, no pause), every group's query part is the database row: one definition each."""
    rows = np.arange(450)  # the unmirrored range [0, 450)
    tracker, own = SpeechTracker(1), np.zeros(1, np.int64)
    cues = [tracker.step(own, take.audio[t * SPF : (t + 1) * SPF][None]) for t in range(450)]
    future = db.features[rows][:, group_slices()["future"]]
    live = LiveFrames(
        speaking=np.concatenate([c.speaking for c in cues]),
        since_onset=np.concatenate([c.since_onset for c in cues]),
        predicted=np.concatenate([future, np.full((450, 1), 0.5, np.float32)], axis=1),  # + a speaking probability
        settled=np.zeros((450, 1)),
        rest_future=np.full(future.shape[1], 7.0, np.float32),
    )
    assert tuple(db.weights) == GROUP_NAMES and db.features.shape[1] == N_FEATURES
    assert live.speaking.any() and (~live.speaking).any() and (live.since_onset == 0).any()
    assert np.array_equal(live_query(live, db.features[rows]), db.features[rows])
    # a settled pause: only the future moves, to his rest's
    settled = live_query(replace(live, settled=np.ones((450, 1))), db.features[rows])
    changed = np.flatnonzero((settled != db.features[rows]).any(axis=0))
    assert set(changed) == set(range(N_FEATURES)[group_slices()["future"]]) and np.all(settled[:, changed] == 7.0)


def test_strictly_causal(take, db, predictor):
    """Changing the audio from frame 40 on changes no output frame before 40 (with the predictor)."""
    other = take.audio.copy()
    rng = np.random.default_rng(0)
    other[540 * SPF :] = rng.normal(0, 0.1, len(other) - 540 * SPF).astype(np.float32)
    g = MatchingStream(db, MatchingConfig(margin=0.0), predictor)  # switches often: the change shows soon
    a = run(g, take, 500, 580)
    g.reset()
    b = run(g, take, 500, 580, audio=other)
    assert np.array_equal(a[:40], b[:40])
    assert not np.allclose(a[40:], b[40:])  # the change does reach later frames


def test_no_pop_over_clip_switches(take, db, predictor):
    """Inertialization (and the acceleration cap) keep every switch under the real motion's largest joint
    acceleration; without them (a half-life of 0.1 ms, no cap) the same switches pop."""
    real_max = accelerations(take.pose[:450]).max()
    out = {}
    for h in (0.15, 1e-4):
        cap = 99.0 if h > 0.01 else 0.0  # the raw run without the acceleration cap too
        g = MatchingStream(db, MatchingConfig(halflife_s=h, margin=0.0, accel_cap_percentile=cap), predictor)
        pose = run(g, take, 450, 765)
        out[h] = (int((accelerations(pose) > real_max).any(axis=1).sum()), int(g.kernel.switches[0]))
    (pops, switches), (raw_pops, raw_switches) = out[0.15], out[1e-4]
    assert switches >= 10 and raw_switches >= 10, out
    assert pops <= 1, out
    assert raw_pops >= 3, out  # the check can fail: unblended switches pop


def test_intensity_zero_plays_idle_frames_only_and_moves(take, db):
    g = MatchingStream(db)
    g.intensity = 0.0
    rows, poses = [], []
    for t in range(450, 765):
        poses.append(g.step(take.audio[t * SPF : (t + 1) * SPF], take.face[t], take.head[t]))
        rows.append(g.playing_row)
    rows = np.array(rows)
    assert g.kernel.idle_play[rows[3:]].all()  # after the first search, idle rows only
    poses = np.array(poses)
    assert np.degrees(np.abs(np.diff(poses, axis=0)).max()) > 0.5  # not frozen
    assert len(np.unique(db.segment[rows] * 10_000 + rows // 30)) >= 3  # not one stretch looping
    assert float(gain_of(0.0)) == 0.5 and float(gain_of(1.0)) == 1.0 and float(gain_of(1.3)) == pytest.approx(1.3)


def test_silence_fades_to_idle(take, db):
    g = MatchingStream(db)
    silent = np.zeros(SPF, np.float32)
    rows = [g.playing_row]
    for _ in range(60):
        g.step(silent, np.zeros(52, np.float32), take.head[0])
        rows.append(g.playing_row)
    assert g.kernel.idle_play[np.array(rows[2:])].all()


def test_intensity_change_never_pops(take, db):
    g = MatchingStream(db)
    a = run(g, take, 450, 500)
    g.intensity = 1.3
    b = run(g, take, 500, 560)
    pose = np.concatenate([a, b])
    real_max = accelerations(take.pose[:450]).max()
    assert (accelerations(pose[40:70]) <= real_max).all()
    assert g.intensity == pytest.approx(1.3)


def test_batched_equals_single_streams(take, db, predictor):
    starts = (450, 520, 600)
    singles = []
    for s in starts:
        g = MatchingStream(db, MatchingConfig(), predictor)
        singles.append(run(g, take, s, s + 40))
    kb = BatchedMatchingStreams(db, MatchingConfig(), predictor, capacity=2)  # grows to 3
    extra = kb.open()
    slots = [kb.open() for _ in starts]
    kb.close(extra)
    out = np.zeros((len(starts), 40, 47, 6), np.float32)
    for k in range(40):
        ts = [s + k for s in starts]
        audio = np.stack([take.audio[t * SPF : (t + 1) * SPF] for t in ts])
        out[:, k] = kb.step(slots, audio, take.face[ts], take.head[ts])
    for i in range(len(starts)):
        # one batch against single streams (the predictor batched): float32 rounding, 0.01° (tolerances.py)
        assert_rotations_close(out[i], singles[i], what=f"stream {i}")


def test_style_file_round_trip(tmp_path, take, db, predictor):
    path = save_matching_style(tmp_path / "s.safetensors", db, MatchingConfig(margin=0.7), take.skeleton, predictor)
    ck = load_style(path)
    assert ck.engine == "matching" and ck.fps == FPS and ck.meta["format"] == "facecapges-matching-1"
    assert isinstance(ck, GestureEngine) and ck.display_name == "motion matching (s)"
    assert ck.config.margin == 0.7 and ck.skeleton.names == take.skeleton.names
    assert ck.database_poses().shape == (len(db), 47, 6) and ck.neutral_window.shape[1:] == (47, 6)
    for k, v in db.tensors().items():
        assert np.array_equal(ck.db.tensors()[k], v), k
    a = run(MatchingStream(db, MatchingConfig(margin=0.7), predictor), take, 450, 500)
    b = run(ck.streaming(), take, 450, 500)
    assert np.array_equal(a, b)  # the same engine from its file (float32 kept): the same code path, bit for bit
    # the one whole-recording loop runs this engine as the network, from a history as eval's other samples
    window = take.pose[600:608].astype(np.float32)
    frames = range(450, 500)
    audio = np.stack([take.audio[t * SPF : (t + 1) * SPF] for t in frames])
    inputs = FrameInputs(audio=audio, face=take.face[450:500], head=take.head[450:500], fps=FPS, notes=[])
    by_hand = ck.streaming()
    by_hand.reset(initial_pose=window)
    from_window = generate_poses(ck, inputs, False, window)[0]
    # the same kernel, but generate_poses sets its own thread count: float32 rounding, 0.01° (tolerances.py)
    assert_rotations_close(from_window, run(by_hand, take, 450, 500), what="generate_poses from a window")
    assert np.abs(from_window - b).max() > 1e-3  # the history is really used
    assert_rotations_close(generate_poses(ck, inputs, progress=False)[0], b, what="generate_poses cold")
    assert load_style(style=None).engine == "matching"  # the default style
    assert load_style(style=DEFAULT_NETWORK_STYLE).engine == "network"


def test_old_style_file_with_a_director_loads_and_ignores_it(tmp_path, take, db, predictor):
    """A style written while the "director" experiment (issue #25, removed: docs/matching.md) was in the
    product may carry its network's tensors, a ``director`` meta entry and its settings in the engine
    config, and every style before issue #35 a ``db.energy_class``: it loads, they are ignored, and it plays
    as the same style without them."""
    import torch
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    path = save_matching_style(tmp_path / "new.safetensors", db, MatchingConfig(), take.skeleton, predictor)
    tensors = load_file(str(path))
    with safe_open(str(path), "pt") as f:
        meta = json.loads(f.metadata()["facecapges"])
    assert "db.energy_class" not in tensors  # no longer written (read by nothing)
    tensors["director.audio.weight"] = torch.ones(4, 3)
    tensors["db.energy_class"] = torch.zeros(len(db), dtype=torch.int8)
    meta["director"] = {"format": "facecapges-director-1", "model_config": {}, "neutral_window": []}
    meta["engine_config"].update(direction_weight=2.0, direction_at_onsets=True)
    old = tmp_path / "old.safetensors"
    save_file(tensors, str(old), metadata={"facecapges": json.dumps(meta)})
    style = load_style(old)
    assert not hasattr(style, "director") and not hasattr(style.config, "direction_weight")
    a = run(load_style(path).streaming(), take, 450, 490)
    assert np.array_equal(a, run(style.streaming(), take, 450, 490))


@pytest.fixture(scope="module")
def zeggs_piece(tmp_path_factory):
    """16 s of the ZEGGS take (motion + speech), written to tmp: built at run time, never committed."""
    from facecapges.io.audio import load_audio, save_audio
    from facecapges.io.bvh import read_bvh, write_bvh

    d = tmp_path_factory.mktemp("zeggs")
    bvh = read_bvh(shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"))
    n = int(16 * bvh.fps)
    write_bvh(d / "piece.bvh", bvh.skeleton, bvh.motion[:n], bvh.fps)
    audio = load_audio(shared_file("data/zeggs/067_Speech_2_x_1_0.wav"))
    save_audio(d / "piece.wav", audio[: 16 * timing.AUDIO_SR])
    return d / "piece.bvh", d / "piece.wav"


def test_styles_build_end_to_end_on_zeggs(tmp_path, zeggs_piece):
    env_dir = tmp_path / "styles"
    env = {"FACECAPGES_STYLES": str(env_dir)}
    import os

    env = {**os.environ, **env}
    bvh, wav = zeggs_piece
    p = cli("styles", "build", "zeggs-mm", "--take", str(bvh), str(wav), "--steps", "20", env=env)
    assert p.returncode == 0, p.stderr[-3000:]
    style = env_dir / "zeggs-mm.safetensors"
    card = (env_dir / "zeggs-mm.md").read_text()
    assert "ND" in card and "never distribute" in card
    listed = json.loads(cli("styles", "--json", env=env).stdout)
    row = next(r for r in listed if r["name"] == "zeggs-mm")
    assert row["engine"] == "matching" and row["path"] == str(style)
    out = tmp_path / "g.bvh"
    p = cli("generate", "--audio", str(wav), "--out", str(out), "--style", "zeggs-mm", env=env)
    assert p.returncode == 0 and out.is_file(), p.stderr[-3000:]
    p = cli("styles", "build", "zeggs-mm", "--take", str(bvh), str(wav), "--steps", "20", env=env)
    refused(p, "--force")  # an installed style is not replaced without --force


@pytest.mark.slow
def test_styles_build_of_a_retargeted_zeggs_take_in_a_pipe(tmp_path, zeggs_piece):
    """The README's path for other skeletons (`retarget`, then `styles build`), with the ZEGGS take beside its
    LICENSE-ZEGGS.md, run as a real process whose output is a pipe (a log, CI): the predictor's training prints
    progress lines on stderr (rich's bar draws nothing there), the card takes CC BY-NC-ND 4.0 from the licence
    file (not "the user's own"), and `styles` lists it by its take, not as "speaker None"."""
    import os
    import shutil

    from runtime_helpers import cli_process

    bvh, wav = zeggs_piece
    d = tmp_path / "zeggs"
    d.mkdir()
    shutil.copy(shared_file("data/zeggs/LICENSE-ZEGGS.md"), d / "LICENSE-ZEGGS.md")  # as it comes with ZEGGS
    shutil.copy(wav, d / "piece.wav")
    p = cli("retarget", str(bvh), "--out", str(d / "piece_beat.bvh"))
    assert p.returncode == 0, p.stderr[-2000:]
    env = {**os.environ, "FACECAPGES_STYLES": str(tmp_path / "styles"), "FACECAPGES_PROGRESS_SECONDS": "0"}
    p = cli_process("styles", "build", "zeggs-beat", "--take", str(d / "piece_beat.bvh"), str(d / "piece.wav"),
                    "--steps", "12", env=env, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = [x for x in p.stderr.splitlines() if x.startswith("speech predictor: ")]
    assert len(lines) >= 3 and "12/12 (100 %)" in lines[-1] and lines[-1].endswith(("done", ")")), p.stderr[-2000:]
    assert "\x1b[" not in p.stderr  # plain lines, no terminal control codes
    card = (tmp_path / "styles" / "zeggs-beat.md").read_text()
    assert "Licence: CC BY-NC-ND 4.0" in card and "never distribute" in card and "user's own" not in card, card
    listed = cli("styles", env=env).stdout
    row = next(x for x in listed.splitlines() if "zeggs-beat" in x)
    assert "None" not in row and "piece_beat.bvh" in row, row


@pytest.mark.parametrize(
    "args, words",
    [
        (["--take", "missing.bvh", "missing.wav"], ["missing.bvh"]),
        (["--take", "{wav}", "{wav}"], ["must be a .bvh"]),
        (["--take", "{bvh}"], ["two paths"]),
        (["--take", "{bvh}", "{bvh}"], ["2_scott_0_1_1.bvh"]),
    ],
)
def test_styles_build_refuses_bad_takes(tmp_path, args, words):
    bvh, wav = shared_file("data/beat/2_scott_0_1_1.bvh"), shared_file("data/beat/2_scott_0_1_1.wav")
    args = [a.format(bvh=bvh, wav=wav) for a in args]
    p = cli("styles", "build", "bad", *args, "--out", str(tmp_path / "x.safetensors"))
    refused(p, *words)
    assert not (tmp_path / "x.safetensors").exists()


def test_compiled_blend_equals_the_quaternion_formulas():
    """``kernels.step_offsets`` (the matcher's and the idle layer's inertialized frame) and ``kernels.dial`` against
    the same formulas in NumPy (``decay_spring``, :mod:`facecapges.rotations`): within 1e-12 (libm's exp, sin, cos
    and atan2 against NumPy's own, a sum in another order), with and without the acceleration cap biting."""
    from facecapges import rotations as rot
    from facecapges.matching import kernels

    rng = np.random.default_rng(4)
    S, J = 5, 47
    def unit(*shape):
        q = rng.normal(size=(*shape, 4))
        return rot.standardize_quaternion(q / np.linalg.norm(q, axis=-1, keepdims=True))

    x, v, hl = rng.normal(0, 0.3, (S, J, 3)), rng.normal(0, 2.0, (S, J, 3)), rng.uniform(0.05, 0.6, S)
    base, prev = unit(3, J), unit(S, 2, J)
    slots = np.array([4, 0, 2])
    for cap in (-1.0, 50.0):  # no cap; a cap every stream is over
        x1, v1, prev1, out = x.copy(), v.copy(), prev.copy(), np.empty((3, J, 4))
        kernels.step_offsets(slots, x1, v1, hl, base, prev1, cap, 15.0, True, out)
        xs, vs = inz.decay_spring(x[slots], v[slots], hl[slots][:, None, None], 1.0 / 15.0)
        want = rot.quaternion_multiply(rot.quaternion_exp(xs), base)
        if cap > 0:
            p1, p2 = prev[slots, 1], prev[slots, 0]
            pred = rot.quaternion_multiply(rot.quaternion_multiply(p1, rot.quaternion_invert(p2)), p1)
            d = rot.quaternion_log(
                rot.standardize_quaternion(rot.quaternion_multiply(want, rot.quaternion_invert(pred)))
            )
            total = np.sqrt((d * d).sum(axis=(1, 2))) * 15.0**2
            assert (total > cap).all()
            want = rot.quaternion_multiply(rot.quaternion_exp(d * (cap / total)[:, None, None]), pred)
            xs = rot.quaternion_log(
                rot.standardize_quaternion(rot.quaternion_multiply(want, rot.quaternion_invert(base)))
            )
        np.testing.assert_allclose(out, want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(x1[slots], xs, rtol=0, atol=1e-12)
        np.testing.assert_allclose(v1[slots], vs, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(prev1[slots, 0], prev[slots, 1])  # shifted: the last, then the pose shown
        np.testing.assert_array_equal(prev1[slots, 1], out)
        np.testing.assert_array_equal(x1[[1, 3]], x[[1, 3]])  # other slots untouched
    mean, slow, gain = unit(J), rng.normal(0, 0.2, (S, J, 3)), np.array([1.0, 1.3, 0.5])
    q, slow1 = base.copy(), slow.copy()
    kernels.dial(slots, q, mean, slow1, 0.2, gain)
    dev = rot.quaternion_log(
        rot.standardize_quaternion(rot.quaternion_multiply(rot.quaternion_invert(mean)[None], base))
    )
    smooth = slow[slots] + 0.2 * (dev - slow[slots])
    np.testing.assert_allclose(slow1[slots], smooth, rtol=0, atol=1e-12)
    want = rot.quaternion_multiply(mean[None], rot.quaternion_exp(dev + (gain - 1.0)[:, None, None] * smooth))
    np.testing.assert_array_equal(q[0], base[0])  # gain 1: unchanged
    np.testing.assert_allclose(q[1:], want[1:], rtol=0, atol=1e-12)
