"""A pause like a person's (issue #38; ``facecapges.matching.idle``): on the shipped matching style a muted-mic
pause settles into his rest and a procedural idle at his amplitude and stays there, without a pop at the pause's
start or end, never frozen, and speech takes the gestures back within 0.3 s; one stream and a batch slot agree."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import shared_file
from facecapges import timing
from facecapges.evaluation import conversation as cv
from facecapges.io.audio import load_audio
from facecapges.matching.takes import load_take
from facecapges.rotations import identity_rot6d
from facecapges.styles import load_style
from tolerances import assert_rotations_close

SPF, FPS = timing.samples_per_frame(), timing.MODEL_FPS


@pytest.fixture(scope="module")
def style():
    return load_style(style="beat2-scott-mm")


@pytest.fixture(scope="module")
def ref(style):
    """His real motion: the training frames of both paired takes (as the card's conversation table)."""
    beat = "data/beat/"
    t1 = load_take(shared_file(beat + "2_scott_0_1_1.bvh"), shared_file(beat + "2_scott_0_1_1.wav"))
    t2 = load_take(shared_file("data/beat2/2_scott_0_2_2.npz"), shared_file(beat + "2_scott_0_2_2.wav"), t1.skeleton)
    takes = (t1, t2)
    return cv.reference(
        style.skeleton, [t.pose[: t.train_until] for t in takes], [t.audio[: t.train_until * SPF] for t in takes]
    )


@pytest.fixture(scope="module")
def zeros_clip():
    """10 s of his unseen speech, 15 s of digital zeros (a muted mic), 10 s more (the conversation set's way)."""
    u = load_audio(shared_file("data/beat/2_scott_0_4_4.wav"), timing.AUDIO_SR)
    S, P = int(10 * timing.AUDIO_SR), int(15 * timing.AUDIO_SR)
    return cv._insert(u[:S], u[S : 2 * S], np.zeros(P, np.float32), "zeros", "zeros")


def _pops_near_edges(sc: cv.ClipScore, pause: np.ndarray, within_s: float = 1.0) -> list[int]:
    """Pop frames (the conversation metric's rule) within ``within_s`` of a pause's start or end."""
    edges = [e for a, b in cv._runs(pause) for e in (a, b)]
    w = int(within_s * FPS)
    return [p for p in sc.pops if any(abs(p - e) <= w for e in edges)]


def _settled_after(pose, skel, pause: np.ndarray, from_s: float) -> float:
    """The largest 1-s mean wrist speed (cm/s) from ``from_s`` into the pause to its end (the settle rule's speed)."""
    from facecapges.evaluation.synchrony import wrist_positions

    sm = cv._smooth(cv.wrist_speed(wrist_positions(skel, pose)), int(cv.SETTLE_WINDOW_S * FPS))
    a, b = cv._runs(pause)[0]
    return float(sm[a + int(from_s * FPS) : b].max())


def test_a_zeros_pause_settles_and_stays_settled(style, ref, zeros_clip):
    """With the idle layer a 15-s zeros pause settles (1-s wrist speed at his idle level) within 2 s (1.5 s here;
    issue #38 asks ~1 s: not reached, see docs/matching.md) and stays settled to its end — no stroke in the pause
    (the engine before: settles after 3.1 s and its 1-s wrist speed climbs back to 25 cm/s, over his idle level of
    18); no pop in the pause or within 1 s of its start and end, never still for 2 s, and speech brings the
    gestures back within 0.3 s."""
    pose = cv.generate(style, zeros_clip.audio)
    sc = cv.score(style.skeleton, pose, zeros_clip.pause, ref)
    assert sc.settle_s <= 2.0, sc
    assert _settled_after(pose, style.skeleton, zeros_clip.pause, 2.0) <= ref.idle_speed
    assert sc.pops_pause_per_min == 0 and not _pops_near_edges(sc, zeros_clip.pause), sc
    assert sc.resume_s <= 0.3, sc
    assert sc.longest_still_s < 2.0, sc  # an idle, not a statue
    assert sc.pause_over_speech_speed < 0.4, sc


def test_without_the_layer_the_same_pause_settles_late_and_moves_again(style, ref, zeros_clip):
    """The checks above fail on the engine without the layer (``idle_layer=False``: the behaviour before it)."""
    old = replace(style, config=replace(style.config, idle_layer=False))
    pose = cv.generate(old, zeros_clip.audio)
    sc = cv.score(style.skeleton, pose, zeros_clip.pause, ref)
    assert sc.settle_s > 2.0, sc
    assert _settled_after(pose, style.skeleton, zeros_clip.pause, 2.0) > ref.idle_speed


def test_the_idle_moves_at_his_rest_amplitude(style):
    """The procedural idle's amplitude per joint and axis is measured from his rest rows (a few degrees at most on
    the arms, under a degree or two on the spine and neck), and its frequency is finite."""
    layer = style.batched(1).idle_layer
    assert layer is not None
    amp = np.degrees(layer.motion.amplitude)
    assert amp.shape == (11, 3) and (amp >= 0).all() and amp.max() < 5.0 and amp.max() > 0.1, amp
    assert np.isfinite(layer.motion.frequency).all() and layer.motion.frequency.max() < 5.0
    assert len(layer.motion.rest) > 10  # rest rows to settle into


def test_one_stream_and_a_batch_slot_agree_through_a_pause(style, zeros_clip):
    """A slot of a batch whose other slot speaks gives the single stream's poses through the pause's start."""
    n = 60
    a0 = 140 * SPF  # 10 frames before the zeros begin
    audio = zeros_clip.audio[a0 : a0 + n * SPF].reshape(n, SPF)
    other = zeros_clip.audio[: n * SPF].reshape(n, SPF)
    face, head = np.zeros(52, np.float32), identity_rot6d().astype(np.float32)
    one = style.streaming()
    single = np.stack([one.step(audio[k], face, head) for k in range(n)])
    batch = style.batched(2)
    s0, s1 = batch.open(), batch.open()
    got = np.stack([
        batch.step([s0, s1], np.stack([other[k], audio[k]]), np.stack([face, face]), np.stack([head, head]))[1]
        for k in range(n)
    ])
    assert_rotations_close(got, single)


def test_a_style_file_s_idle_settings_are_checked():
    """A style's ``engine_config`` may set the layer's knobs; a wrong value is one clear ValueError."""
    from facecapges.matching.style import check_engine_config

    assert check_engine_config({"idle_rest": "mean", "idle_torso": "procedural"}).idle_rest == "mean"
    for bad in ({"idle_rest": "sideways"}, {"idle_torso": 3}, {"idle_enter_halflife_s": 0.0}, {"idle_layer": 1}):
        with pytest.raises(ValueError, match="engine_config idle_"):
            check_engine_config(bad)


@pytest.fixture(scope="module")
def heldout_zeros_clip():
    """The card's ``heldout-zeros 2_scott_0_1_1`` clip: the take's held-out 20 % cut in half around 15 s of zeros
    (its speech ends mid-stroke, the hardest pause to settle)."""
    t1 = load_take(shared_file("data/beat/2_scott_0_1_1.bvh"), shared_file("data/beat/2_scott_0_1_1.wav"))
    a = t1.audio[t1.train_until * SPF : t1.n_frames * SPF]
    half = len(a) // 2
    return cv._insert(a[:half], a[half:], np.zeros(int(cv.PAUSE_S * timing.AUDIO_SR), np.float32), "h", "zeros")


def test_a_pause_after_a_stroke_settles_sooner(style, ref, zeros_clip, heldout_zeros_clip):
    """Speech that ends mid-stroke (held-out 1_1): the layer takes the pause one frame sooner (0.47 s after the last
    speech-like frame) and carries none of the stroke's speed into it (``idle_enter_velocity`` 0, the acceleration
    cap spreading the brake), so the arms are settled — the next second's wrist speed at his idle level — 0.60 s
    into the pause (0.73 before; 1.53 s by the trailing 1-s rule, 1.67 before), without a pop at its start and with
    the unseen clip's figures no worse (docs/matching.md "Settling sooner")."""
    pose = cv.generate(style, heldout_zeros_clip.audio)
    sc = cv.score(style.skeleton, pose, heldout_zeros_clip.pause, ref)
    assert sc.settle_ahead_s <= 0.65 and sc.settle_s <= 1.6, sc
    assert sc.pops_pause_per_min == 0 and not _pops_near_edges(sc, heldout_zeros_clip.pause), sc
    assert sc.resume_s <= 0.3, sc
    u = cv.score(style.skeleton, cv.generate(style, zeros_clip.audio), zeros_clip.pause, ref)
    assert u.settle_ahead_s <= 0.65 and u.settle_s <= 1.6, u


def test_before_the_brake_the_stroke_runs_on_into_the_pause(style, ref, heldout_zeros_clip):
    """The check above fails on the layer as it was (entering 0.53 s after the voice, carrying the stroke's speed)."""
    old = replace(style, config=replace(style.config, idle_after_s=0.53, idle_enter_velocity=1.0))
    sc = cv.score(style.skeleton, cv.generate(old, heldout_zeros_clip.audio), heldout_zeros_clip.pause, ref)
    assert sc.settle_ahead_s > 0.65 and sc.settle_s > 1.6, sc


def test_the_settle_rules_read_a_dead_stop(ref):
    """Arms that stop dead on a pause's first frame after a second at twice his idle speed: settled at once by the
    rule that looks ahead, after half a second by the trailing 1-s mean (its memory of the speech before)."""
    T, a = 60, 30
    pause = np.zeros(T, bool)
    pause[a:] = True
    w = np.zeros((T, 2, 3))
    step = 2.0 * ref.idle_speed / FPS  # cm a frame
    w[:a, :, 0] = np.arange(a)[:, None] * step
    w[a:, :, 0] = w[a - 1, :, 0]
    s = cv.wrist_speed(w)
    assert np.isclose(s[a - 1], 2.0 * ref.idle_speed)
    calm = np.flatnonzero(cv._ahead(s[a:], int(cv.SETTLE_WINDOW_S * FPS)) <= ref.idle_speed)[0] / FPS
    trail = np.flatnonzero(cv._smooth(s, int(cv.SETTLE_WINDOW_S * FPS))[a:] <= ref.idle_speed)[0] / FPS
    assert calm == 0.0 and 0.4 <= trail <= 0.55, (calm, trail)


def _measure(style, q: np.ndarray, skeleton):
    from facecapges.matching.features import group_slices
    from facecapges.matching.idle import IdleMotion

    m, db = style.batched(1), style.db
    rest = m.idle & (db.phase == 0)
    height = db.features[:, group_slices()["position"]].reshape(len(db), 4, 3)[:, :2, 1]
    return IdleMotion.measure(q, db.segment, rest, FPS, "low", wrist_height=height, skeleton=skeleton), rest


def test_the_idle_moves_the_wrists_no_faster_than_the_rest_runs(style):
    """The wrist bound (``IdleMotion.wrist_speed``): a capture's noise that cancels at the wrist — here the elbow
    swinging about the shoulder→wrist axis, the swivel a camera cannot see in depth, 10° sd on every rest row —
    inflates the per-joint amplitudes; replayed independently it moved the wrists faster than the rest rows do. With
    the skeleton the idle's mean wrist speed is bounded by the rest runs'; on his motion capture nothing changes."""
    from facecapges.matching import inertialize as inz
    from facecapges.matching.idle import _wrist_speed, rest_runs
    from facecapges.rotations import quaternion_to_rot6d
    from facecapges.skeleton import UPPER_BODY, upper_body_transforms

    skel = style.skeleton
    q0 = style.batched(1).row_quaternions
    plain, rest = _measure(style, q0, None)
    bounded, _ = _measure(style, q0, skel)
    np.testing.assert_array_equal(bounded.amplitude, plain.amplitude)  # his capture: the bound does not bind

    q = q0.copy()
    rows = np.flatnonzero(rest)
    g, p = upper_body_transforms(skel, quaternion_to_rot6d(q0[rows]))
    rng = np.random.default_rng(0)
    for side in ("Right", "Left"):
        arm = skel.index(f"{side}Arm")
        axis = p[:, skel.index(f"{side}Hand")] - p[:, arm]
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        parent = g[:, skel.parents[arm]]  # the swivel, in the upper arm's parent frame
        local = np.einsum("tji,tj->ti", parent, axis)
        turn = inz.qexp(local * np.radians(10.0) * rng.standard_normal((len(rows), 1)))
        j = UPPER_BODY.index(f"{side}Arm")
        q[rows, j] = inz.qmul(turn, q0[rows, j])
    _, p1 = upper_body_transforms(skel, quaternion_to_rot6d(q[rows]))
    wr = [skel.index("RightHand"), skel.index("LeftHand")]
    np.testing.assert_allclose(p1[:, wr], p[:, wr], atol=1e-3)  # the wrists have not moved

    noisy, _ = _measure(style, q, None)
    fixed, _ = _measure(style, q, skel)
    runs = np.concatenate([_wrist_speed(skel, q[r], FPS) for r in rest_runs(style.db.segment, rest)])
    assert noisy.wrist_speed(skel, FPS) > 1.3 * runs.mean()  # unbounded: faster than the rest rows
    assert fixed.wrist_speed(skel, FPS) <= runs.mean() * 1.005  # a few passes: within 0.5 %
    assert (fixed.amplitude <= noisy.amplitude + 1e-12).all() and fixed.amplitude.max() > 0
