"""Retargeting other skeletons onto BEAT, on the real files: BEAT round trip, ZEGGS arm directions, errors."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_file
from facecapges import rotations as rot
from facecapges.data.retarget import (
    auto_map,
    load_map,
    rest_corrections,
    retarget_bvh,
    retarget_motion,
    shipped_map_path,
)
from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import (
    UPPER_BODY,
    global_transforms,
    local_matrices,
    motion_to_euler,
    motion_to_pose,
    pose_to_motion,
)
from runtime_helpers import cli

ARM_BONES = [(f"{s}{a}", f"{s}{b}") for s in ("Right", "Left") for a, b in
             (("Shoulder", "Arm"), ("Arm", "ForeArm"), ("ForeArm", "Hand"), ("Hand", "HandMiddle1"),
              ("HandIndex1", "HandIndex2"), ("HandThumb2", "HandThumb3"))]


def run(*args):
    return cli(*map(str, args))


@pytest.fixture(scope="module")
def beat():
    return read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))


@pytest.fixture(scope="module")
def zeggs_path():
    return shared_file("data/zeggs/067_Speech_2_x_1_0.bvh")


def fk(bvh_skel, motion):
    _, euler = motion_to_euler(bvh_skel, motion)
    return global_transforms(bvh_skel, local_matrices(bvh_skel, euler))


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def test_beat_onto_beat_is_the_identity(beat, tmp_path):
    assert auto_map(beat.skeleton).name == "beat"
    pose, mask = retarget_motion(beat.skeleton, beat.motion, beat.skeleton, load_map("beat"))
    ref, _ = motion_to_pose(beat.skeleton, beat.motion)
    err = np.degrees(rot.geodesic_angle(rot.rot6d_to_matrix(pose.astype(np.float64)),
                                        rot.rot6d_to_matrix(ref.astype(np.float64))))
    assert mask.all()
    assert err.max() < 1e-3, err.max()
    # through the command: the written file moves every joint as the original does
    src = shared_file("data/beat/2_scott_0_1_1.bvh")
    res = run("retarget", src, "--out", tmp_path / "rt.bvh", "--target", src)
    assert res.returncode == 0, res.stderr
    assert "47/47 joints" in res.stdout
    out = read_bvh(tmp_path / "rt.bvh")
    assert out.fps == beat.fps and out.n_frames == beat.n_frames
    P0, P1 = fk(beat.skeleton, beat.motion)[1], fk(out.skeleton, out.motion)[1]
    assert np.abs(P0 - P1).max() < 0.01  # cm


def test_zeggs_arm_directions_match(beat, zeggs_path, tmp_path):
    res = run("retarget", zeggs_path, "--out", tmp_path / "z.bvh", "--target", shared_file("data/beat/2_scott_0_1_1.bvh"))
    assert res.returncode == 0, res.stderr
    assert "joint map 'zeggs'" in res.stdout and "41/47 joints" in res.stdout and "RightHandIndex" in res.stdout
    src, out = read_bvh(zeggs_path), read_bvh(tmp_path / "z.bvh")
    assert out.skeleton.names == beat.skeleton.names and out.fps == 30 and out.n_frames == src.n_frames
    Gs, Ps = fk(src.skeleton, src.motion)
    _, Pt = fk(out.skeleton, out.motion)
    hips = Gs[:, src.skeleton.index("Hips")]
    Ps = np.einsum("tji,tkj->tki", hips, Ps - Ps[:, :1])  # the source seen from its pelvis, like BEAT's pose
    for a, b in ARM_BONES:
        d_t = Pt[:, beat.skeleton.index(b)] - Pt[:, beat.skeleton.index(a)]
        d_s = Ps[:, src.skeleton.index(b)] - Ps[:, src.skeleton.index(a)]
        err = angles_deg(d_t, d_s)
        assert np.median(err) < 0.5 and err.max() < 2.0, (a, b, np.median(err), err.max())
    # the arms really move: the test is not comparing two rest poses
    fore = Pt[:, beat.skeleton.index("RightHand")] - Pt[:, beat.skeleton.index("RightForeArm")]
    assert angles_deg(fore, fore[:1]).max() > 30


def test_stated_zeggs_corrections_are_the_computed_ones(beat, zeggs_path):
    jmap = load_map("zeggs")
    src = read_bvh(zeggs_path)
    stated = jmap.corrections
    jmap.corrections = {}
    computed = rest_corrections(jmap, src.skeleton, beat.skeleton)
    for t, q in computed.items():
        expect = stated.get(t, np.eye(3))
        assert np.degrees(rot.geodesic_angle(q, expect)) < 0.01, t


def test_resample_and_help(zeggs_path, tmp_path):
    target = shared_file("data/beat/2_scott_0_1_1.bvh")
    r = retarget_bvh(zeggs_path, read_bvh(target).skeleton, fps=15)
    assert r.fps == 15 and r.n_frames == 1033
    res = run("retarget", "--help")
    assert res.returncode == 0 and "--map" in res.stdout and "--fps" in res.stdout


def test_unmappable_skeleton_names_missing_joints(zeggs_path, tmp_path):
    text = zeggs_path.read_text()
    bad = tmp_path / "bad.bvh"
    bad.write_text(text.replace("JOINT RightForeArm\n", "JOINT RightElbow\n").replace("JOINT LeftHand\n",
                                                                                       "JOINT LeftWrist\n"))
    res = run("retarget", bad, "--out", tmp_path / "o.bvh", "--target", shared_file("data/beat/2_scott_0_1_1.bvh"))
    assert res.returncode != 0 and "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")
    assert "RightForeArm" in lines[0] and "LeftHand" in lines[0] and "bad.bvh" in lines[0]
    assert not (tmp_path / "o.bvh").exists()
    with pytest.raises(UserError, match="unknown joint map"):
        load_map("nosuchmap")


def test_existing_output_needs_force(zeggs_path, tmp_path):
    (tmp_path / "o.bvh").write_text("keep")
    res = run("retarget", zeggs_path, "--out", tmp_path / "o.bvh")
    assert res.returncode != 0 and "--force" in res.stderr
    assert (tmp_path / "o.bvh").read_text() == "keep"


def test_masked_joints_follow_their_parent(beat, zeggs_path):
    src = read_bvh(zeggs_path)
    pose, mask = retarget_motion(src.skeleton, src.motion[:50], beat.skeleton, load_map("zeggs"))
    missing = [n for n, m in zip(UPPER_BODY, mask) if not m]
    assert sorted(missing) == sorted(f"{s}Hand{f}" for s in ("Right", "Left") for f in ("Index", "Ring", "Pinky"))
    R = rot.rot6d_to_matrix(pose[:, ~mask].astype(np.float64))
    assert np.allclose(R, np.eye(3), atol=1e-5)
    assert pose_to_motion(beat.skeleton, pose).shape == (50, beat.skeleton.n_channels)


def test_own_joint_map_for_other_names(beat, zeggs_path, tmp_path):
    """Bring your own mocap: other joint names + a written map (no stated corrections) = the shipped result."""
    import json
    import re

    text = re.sub(r"(ROOT|JOINT) (\w+)", r"\1 mocap_\2", zeggs_path.read_text())
    mine = tmp_path / "mine.bvh"
    mine.write_text(text)
    zmap = json.loads(shipped_map_path("zeggs").read_text())
    own = {"name": "mystudio", "speaker": 101, "joints": {t: f"mocap_{s}" for t, s in zmap["joints"].items()}}
    (tmp_path / "mystudio.json").write_text(json.dumps(own))
    with pytest.raises(UserError, match="cannot map"):
        auto_map(read_bvh(mine).skeleton)
    res = run("retarget", mine, "--map", tmp_path / "mystudio.json", "--out", tmp_path / "o.bvh", "--target",
              shared_file("data/beat/2_scott_0_1_1.bvh"))
    assert res.returncode == 0, res.stderr
    assert "joint map 'mystudio'" in res.stdout
    ref = retarget_bvh(zeggs_path, beat.skeleton)
    got = read_bvh(tmp_path / "o.bvh")
    want = pose_to_motion(beat.skeleton, ref.pose)
    P0, P1 = fk(beat.skeleton, want)[1], fk(got.skeleton, got.motion)[1]
    assert np.abs(P0 - P1).max() < 0.01  # cm
