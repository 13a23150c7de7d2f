"""BEAT2 (SMPL-X) takes: the reader, the conversion to the BEAT upper body, and ``prepare`` on BEAT2's layout.

The conversion is checked against the BVH of the same take (the calibration pair in
../shared/data) on the take's last 20 %, which the shipped corrections were not fitted
on (they use the first 80 %: ``fit_map``). The fuzz property counts its cases and
prints them at the end of the session, as tests/test_fuzz.py does.
"""

from __future__ import annotations

import collections
import dataclasses
import io
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import shared_file
from facecapges import rotations as rot
from facecapges.arkit import arkit_index
from facecapges.data import beat2
from facecapges.data.prepare import holdout_frame, needs_target, prepare
from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY

NPZ_11 = "data/beat2/2_scott_0_1_1.npz"
NPZ_22 = "data/beat2/2_scott_0_2_2.npz"
BVH_11 = "data/beat/2_scott_0_1_1.bvh"
CASES: collections.Counter = collections.Counter()

# Held-out bounds (median, p95) in degrees per joint group. Measured on the last 20 %
# (2026-12-01): spine/neck/head 3.0 / 5.3, shoulders/arms 5.7 / 16.7, hands 6.7 / 17.9,
# fingers 5.2 / 17.2 (2026-12-02, with the finger amplitude gains: 2.3 / 10.2; without them the
# bound below fails). The bounds leave ~1.5x room for a refit on other frames; a
# conversion without the fitted corrections (15.9 / 43.0 over all joints) is far above
# them (test below), and so are the arms without their twist lines (hands 13.7 / 40.5).
BOUNDS = {
    "spine/neck/head": (5.0, 9.0),
    "shoulders/arms": (9.0, 25.0),
    "hands": (10.0, 27.0),
    "fingers": (4.0, 15.0),
}


@pytest.fixture(scope="module", autouse=True)
def _report_cases(request):
    yield
    reporter = request.config.pluginmanager.getplugin("terminalreporter")
    if reporter is not None and sum(CASES.values()):
        reporter.write_line(f"beat2 fuzz cases tried: {sum(CASES.values())} ({dict(CASES)})")


@pytest.fixture(scope="module")
def pair_errors():
    return beat2.pair_errors(shared_file(NPZ_11), shared_file(BVH_11))


def test_time_alignment_of_the_pair():
    """The npz is 30 fps; BVH frame i matches npz frame 2i − 1 (one 30 fps frame), elbows at r > 0.98."""
    take = beat2.read_beat2(shared_file(NPZ_11))
    L, fps = beat2.bvh_locals(shared_file(BVH_11))
    lag, r = beat2.measure_lag(take.poses, take.fps, L, fps)
    assert (take.fps, fps, lag) == (30.0, 15.0, -1) and r > 0.98
    assert beat2.load_map().info["lag_source_frames"] == -1


def test_conversion_error_on_the_held_out_part(pair_errors):
    errors, frames = pair_errors
    held = frames >= holdout_frame(957)
    assert held.sum() >= 180
    figures = beat2.group_figures(errors[held])
    print({g: (round(m, 1), round(p, 1)) for g, (m, p) in figures.items()})
    for group, (med_max, p95_max) in BOUNDS.items():
        med, p95 = figures[group]
        assert med <= med_max and p95 <= p95_max, (group, med, p95)


def test_fitted_corrections_are_what_makes_it_match(pair_errors):
    """Without the corrections (identity, no twist lines) the held-out arms are far off."""
    m = beat2.load_map()
    bare = beat2.Beat2Map(np.broadcast_to(np.eye(3), m.left.shape).copy(), np.eye(3)[None].repeat(47, 0), 0, 1)
    bare.info["lag_source_frames"] = -1
    errors, frames = beat2.pair_errors(shared_file(NPZ_11), shared_file(BVH_11), bare)
    held = frames >= holdout_frame(957)
    bare_fig = beat2.group_figures(errors[held])
    fitted = beat2.group_figures(pair_errors[0][pair_errors[1] >= holdout_frame(957)])
    assert bare_fig["all"][0] > 2 * fitted["all"][0]
    assert bare_fig["shoulders/arms"][0] > BOUNDS["shoulders/arms"][0]


def _acceleration(R: np.ndarray) -> np.ndarray:
    d2 = R[2:] - 2.0 * R[1:-1] + R[:-2]
    return np.sqrt((d2**2).sum((-1, -2)))


def test_converted_fingers_move_no_harder_than_beats_own():
    """The SMPL-X fit's finger joints jitter about every axis and its thumbs move 2–5x as far as BEAT's: on the
    held-out frames of the pair, without the finger gains the converted thumbs' 99th-percentile acceleration is
    ~3x that of BEAT's own mocap of the same frames; with them it is not above it."""
    m = beat2.load_map()
    take = beat2.read_beat2(shared_file(NPZ_11))
    L, fps = beat2.bvh_locals(shared_file(BVH_11))
    M, Lb, frames = beat2.aligned_pair(take, L, fps, int(m.info["lag_source_frames"]))
    held = frames >= holdout_frame(957)
    thumbs = [UPPER_BODY.index(n) for n in UPPER_BODY if "Thumb" in n]
    ref = np.percentile(_acceleration(Lb[held][:, thumbs]), 99)
    with_gains = np.percentile(_acceleration(beat2.corrected(M, m)[held][:, thumbs]), 99)
    without = np.percentile(_acceleration(beat2.corrected(M, dataclasses.replace(m, gains={}))[held][:, thumbs]), 99)
    assert without > 2.0 * ref and with_gains < 1.2 * ref, (without / ref, with_gains / ref)
    assert set(m.gains) == set(beat2.GAIN_JOINTS)


def test_shipped_map_is_the_refit_on_the_first_80_percent(tmp_path):
    refit = beat2.fit_map(shared_file(NPZ_11), shared_file(BVH_11))
    shipped = beat2.load_map()
    assert np.abs(refit.left - shipped.left).max() < 1e-5 and np.abs(refit.right - shipped.right).max() < 1e-5
    assert all(np.abs(refit.twist[n] - shipped.twist[n]).max() < 1e-5 for n in shipped.twist)
    assert all(np.abs(refit.gains[n][1] - shipped.gains[n][1]).max() < 1e-5 for n in shipped.gains)
    assert math.isclose(refit.jaw_scale, shipped.jaw_scale, rel_tol=1e-5)
    out = beat2.write_map(refit, tmp_path / "m.json")
    with pytest.raises(UserError, match="--force"):
        beat2.write_map(refit, out)
    again = beat2.load_map(out)
    assert np.allclose(again.left, refit.left, atol=1e-6)


def test_jaw_statistics_are_beats():
    mean = np.load(shared_file("data/beat/stats/face_mean.npy"), allow_pickle=False)
    std = np.load(shared_file("data/beat/stats/face_std.npy"), allow_pickle=False)
    j = arkit_index("jawOpen")
    assert abs(mean[j] - beat2.BEAT_JAWOPEN_MEAN) < 1e-5 and abs(std[j] - beat2.BEAT_JAWOPEN_STD) < 1e-5


def test_load_beat2_take_new_motion():
    pose, face = beat2.load_beat2_take(shared_file(NPZ_22))
    assert pose.shape == (902, 47, 6) and pose.dtype == np.float32
    assert face.shape == (902, 52) and face.dtype == np.float32
    j = arkit_index("jawOpen")
    others = np.delete(face, j, axis=1)
    assert not others.any() and face[:, j].min() >= 0 and face[:, j].max() <= 1
    assert 0.08 < face[:, j].mean() < 0.35 and face[:, j].std() > 0.03  # a talking jaw, in BEAT's range
    R = rot.rot6d_to_matrix(pose.astype(np.float64))
    step = np.degrees(rot.geodesic_angle(R[1:], R[:-1]))
    assert np.percentile(step, 99.9) < 45  # no flips between frames
    elbow = np.degrees(rot.geodesic_angle(np.eye(3), R[:, UPPER_BODY.index("RightForeArm")]))
    assert elbow.std() > 5  # the arms move


# ------------------------------------------------------------------ bad input
def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


GOOD = {"poses": np.zeros((3, 165), np.float32), "mocap_frame_rate": np.array(30), "trans": np.zeros((3, 3))}


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"poses": GOOD["poses"]}, "no 'mocap_frame_rate'"),
        ({**GOOD, "poses": np.zeros((3, 156), np.float32)}, "shape"),
        ({**GOOD, "poses": np.full((3, 165), np.nan)}, "NaN"),
        ({**GOOD, "poses": np.zeros((1, 165))}, "at least 2"),
        ({**GOOD, "mocap_frame_rate": np.array(0)}, "frame rate"),
        ({**GOOD, "mocap_frame_rate": np.array("30")}, "one number"),
        ({**GOOD, "poses": np.array([[None] * 165] * 3, object)}, "objects"),
        ({**GOOD, "poses": np.zeros((3, 165), bool)}, "dtype"),
        ({**GOOD, "trans": np.zeros((4, 3))}, "trans"),
    ],
)
def test_bad_npz_is_a_user_error(tmp_path, arrays, message):
    p = tmp_path / "2_scott_0_1_1.npz"
    if any(a.dtype == object for a in arrays.values()):
        np.savez(p, **arrays, allow_pickle=True)
    else:
        p.write_bytes(_npz(**arrays))
    with pytest.raises(UserError, match=message):
        beat2.read_beat2(p)


def test_not_an_npz_is_a_user_error(tmp_path):
    for name, data in (("a.npz", b"PK\x03\x04 cut"), ("b.npz", b"hello"), ("c.npz", b"")):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(UserError):
            beat2.read_beat2(tmp_path / name)
    np.save(tmp_path / "d.npy", np.zeros(3))
    with pytest.raises(UserError, match=r"single \.npy"):
        beat2.read_beat2(tmp_path / "d.npy")
    with pytest.raises(UserError, match="not found"):
        beat2.read_beat2(tmp_path / "missing.npz")


FUZZ = settings(
    max_examples=150, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck)
)
GOOD_BYTES = _npz(**GOOD)


@st.composite
def damaged(draw):
    """A valid small take with bytes overwritten, inserted, deleted or cut off."""
    b = bytearray(GOOD_BYTES)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "insert", "delete", "cut"]))
        i = draw(st.integers(0, len(b) - 1)) if b else 0
        if op == "flip" and b:
            b[i] = draw(st.integers(0, 255))
        elif op == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del b[i : i + draw(st.integers(1, 30))]
        else:
            del b[i:]
    return bytes(b)


def _array(shape, dtype, fill):
    if dtype == "U3":
        return np.full(shape, "ab")
    with np.errstate(invalid="ignore", over="ignore"):
        return np.full(shape, fill).astype(dtype)


def _arrays():
    shapes = st.lists(st.integers(0, 4), min_size=0, max_size=3).map(tuple) | st.sampled_from([(3, 165), (2, 165)])
    dtypes = st.sampled_from([np.float32, np.float64, np.int16, np.bool_, np.complex64, "U3"])
    fill = st.sampled_from([0.0, 1.0, np.nan, np.inf, -1e30, 7.0])
    return st.builds(_array, shapes, dtypes, fill)


@st.composite
def headers(draw):
    """An archive whose members' npy headers declare any shape and dtype over any amount of data (issue 34:
    sizes are read from the header and the zip member before anything is unpacked), stored or deflated."""
    import zipfile

    members = {}
    for key in draw(st.lists(st.sampled_from(["poses", "mocap_frame_rate", "trans"]), min_size=1, unique=True)):
        shape = tuple(draw(st.lists(st.sampled_from([0, 1, 2, 3, 165, 10**5, 10**12, 2**62]), max_size=3)))
        dtype = np.dtype(draw(st.sampled_from(["<f8", ">f4", "<i4", "<f2", "|u1", "<c8"])))
        head = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            head, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": draw(st.booleans()), "shape": shape}
        )
        fill = draw(st.sampled_from([0.0, 1.0, 1e300, np.nan, 3 * np.pi]))
        with np.errstate(invalid="ignore", over="ignore"):
            data = np.full(draw(st.integers(0, 2000)), fill).astype(dtype).tobytes()
        members[f"{key}.npy"] = head.getvalue() + data
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]))) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


@FUZZ
@given(st.one_of(damaged(), st.dictionaries(st.sampled_from(["poses", "mocap_frame_rate", "trans"]), _arrays()),
                 headers().map(lambda b: ("headers", b))))
def test_fuzz_read_beat2(tmp_path_factory, case):
    if isinstance(case, tuple):
        CASES["headers"] += 1
        case = case[1]
        kind = None
    else:
        kind = "bytes" if isinstance(case, bytes) else "arrays"
    if kind is not None:
        CASES[kind] += 1
    p = tmp_path_factory.getbasetemp() / "fuzz.npz"
    p.write_bytes(case if isinstance(case, bytes) else _npz(**case))
    try:
        take = beat2.read_beat2(p)
    except UserError as exc:
        assert str(p.name) in str(exc)
        return
    assert take.poses.shape[1:] == (55, 3) and np.isfinite(take.poses).all() and take.fps >= 1
    pose, face = beat2.convert_take(take)
    assert np.isfinite(pose).all() and np.isfinite(face).all()


# ------------------------------------------------------------------ prepare
def _beat2_root(tmp_path, names):
    root = tmp_path / "BEAT2"
    for sub in ("smplxflame_30", "wave16k"):
        (root / sub).mkdir(parents=True)
    for name in names:
        (root / "smplxflame_30" / f"{name}.npz").symlink_to(shared_file(f"data/beat2/{name}.npz"))
        (root / "wave16k" / f"{name}.wav").symlink_to(shared_file(f"data/beat/{name}.wav"))
    return root


def test_prepare_reads_beat2_layout(tmp_path):
    root = _beat2_root(tmp_path, ["2_scott_0_1_1", "2_scott_0_2_2"])
    assert needs_target(root)
    with pytest.raises(UserError, match="--target"):
        prepare(root, tmp_path / "none", progress=False)
    target = read_bvh(shared_file(BVH_11)).skeleton
    index = prepare(root, tmp_path / "cache", progress=False, target=target)
    clips = {c["name"]: c for c in index["clips"]}
    assert sorted(clips) == ["2_scott_0_1_1", "2_scott_0_2_2"] and not index["skipped"]
    for name, T in (("2_scott_0_1_1", 953), ("2_scott_0_2_2", 902)):
        c = clips[name]
        assert (c["n_frames"], c["dataset"], c["origin"], c["speaker"]) == (T, "BEAT2", "beat2", 2)
        assert c["holdout_from"] == int(T * 0.8) and c["face_source"] == "jaw" and c["source_fps"] == 30.0
    with np.load(tmp_path / "cache" / clips["2_scott_0_2_2"]["file"], allow_pickle=False) as z:
        pose, face, audio = z["pose"], z["face"], z["audio"]
    direct_pose, direct_face = beat2.load_beat2_take(shared_file(NPZ_22))
    assert np.array_equal(pose, direct_pose) and np.array_equal(face, direct_face)
    assert len(audio) == math.floor(902 * 16000 / 15)


def test_prepare_beat_and_beat2_together(tmp_path):
    """BEAT's BVH of 1_1 and BEAT2's new 0_2_2: speaker 2 has 64 s + 60 s of paired motion."""
    root = _beat2_root(tmp_path, ["2_scott_0_1_1", "2_scott_0_2_2"])
    (root / "beat").mkdir()
    for suffix in (".bvh", ".wav"):
        (root / "beat" / f"2_scott_0_1_1{suffix}").symlink_to(shared_file(f"data/beat/2_scott_0_1_1{suffix}"))
    (root / "wave16k" / "2_scott_0_1_1.wav").unlink()  # one wav per clip
    assert not needs_target(root)
    index = prepare(root, tmp_path / "cache", progress=False)
    clips = {c["name"]: c for c in index["clips"]}
    assert clips["2_scott_0_1_1"]["origin"] == "beat" and clips["2_scott_0_2_2"]["origin"] == "beat2"
    assert any("the .bvh is used" in w for w in index["warnings"])
    seconds = sum(c["n_frames"] for c in clips.values()) / 15
    assert 123 < seconds < 125 and index["stats"]["2"]["n_frames"] == 957 + 902


def test_bad_correction_map_is_a_user_error(tmp_path):
    good = beat2.load_map().to_dict()
    cases = {
        "not_json.json": "{",
        "list.json": "[]",
        "no_joints.json": '{"jaw": {"offset": 0, "scale_per_rad": 1}}',
        "bad_quat.json": json.dumps(
            {**good, "joints": {**good["joints"], "Spine": {"left": [0, 0, 0, 0], "right": [1, 0, 0, 0]}}}
        ),
        "bad_twist.json": json.dumps({**good, "twist": {"Spine": [1, 2]}}),
        "bad_gains.json": json.dumps({**good, "gains": {"Spine": {"centre": [1, 0, 0, 0], "gain": [1, 1, 1]}}}),
        "nan_gains.json": json.dumps(
            {**good, "gains": {"LeftHandThumb1": {"centre": [1, 0, 0, 0], "gain": [1, "x", 1]}}}
        ),
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(UserError):
            beat2.load_map(tmp_path / name)
    with pytest.raises(UserError, match="not found"):
        beat2.load_map(tmp_path / "missing.json")
