"""The 9-joint ZEGGS takes read as BEAT poses: FK against the stored positions, mask, frame calibration."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_file
from facecapges import rotations as rot
from facecapges import timing
from facecapges.data.joints9 import load_array, load_layout, read_joints9, source_world
from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import (
    UPPER_BODY,
    global_transforms,
    joint_positions,
    local_matrices,
    motion_to_euler,
    pose_to_motion,
)

TAKES = ("001_Neutral_0_x_1_0", "003_Neutral_2_x_1_0")
PRESENT = {"Spine"} | {f"{s}{j}" for s in ("Right", "Left") for j in ("Shoulder", "Arm", "ForeArm", "Hand")}


@pytest.fixture(scope="module")
def target():
    return read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh")).skeleton


def angles_deg(a, b):
    c = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


@pytest.mark.parametrize("take", TAKES)
def test_fk_arm_directions_match_the_stored_positions(take, target):
    path = shared_file(f"data/zeggs9/{take}.npy")
    layout = load_layout("zeggs9")
    r = read_joints9(path, target)
    raw = timing.resample(load_array(path, layout), 60, 15)
    assert r.fps == 15 and r.n_frames == len(raw) == len(np.load(path)[::4])
    assert {n for n, m in zip(UPPER_BODY, r.mask) if m} == PRESENT
    P = joint_positions(target, pose_to_motion(target, r.pose))
    hips = rot.quaternion_to_matrix(raw[:, 0, [6, 3, 4, 5]])  # the hips frame is the skeleton's own
    Ps = np.einsum("tji,tkj->tki", hips, raw[..., :3] - raw[:, :1, :3])
    j = {n: i for i, n in enumerate(layout.joints)}
    for side in ("Right", "Left"):
        for a, b in ((f"{side}Arm", f"{side}ForeArm"), (f"{side}ForeArm", f"{side}Hand")):
            err = angles_deg(P[:, target.index(b)] - P[:, target.index(a)], Ps[:, j[b]] - Ps[:, j[a]])
            assert np.median(err) < 0.5 and err.max() < 2.0, (take, a, b, np.median(err), err.max())
        # the clavicle (not stored) puts BEAT's upper arm where the chest→arm vector points, corrected by the
        # layout's rest correction for the two skeletons' proportions (seen in each chest's frame)
        _, euler = motion_to_euler(target, pose_to_motion(target, r.pose))
        G, P_ = global_transforms(target, local_matrices(target, euler))
        S, pos = source_world(raw, layout)
        chest, arm = target.index("Spine3"), target.index(f"{side}Arm")
        d_t = np.einsum("tji,tj->ti", G[:, chest], P_[:, arm] - P_[:, chest])
        d_s = np.einsum("tji,tj->ti", S["Spine3"], pos[f"{side}Arm"] - pos["Spine3"])
        K, Q = layout.clavicles[f"{side}Shoulder"]["correction"], layout.skeleton_map.corrections["Spine"]
        err = angles_deg(d_t, d_s @ Q @ K.T)
        assert err.max() < 0.5, (take, side, err.max())
        assert angles_deg(d_s, d_s.mean(0)).max() > 5  # the source's clavicle does move


def _hinge_axis(upper: np.ndarray, forearm_dir: np.ndarray) -> np.ndarray:
    """Normal of the plane the forearm direction moves in, in the upper arm's frame."""
    loc = np.einsum("tji,tj->ti", upper, forearm_dir / np.linalg.norm(forearm_dir, axis=-1, keepdims=True))
    return np.linalg.svd(loc, full_matrices=False)[2][-1]


def test_upper_arm_frames_agree_with_the_zeggs_bvh_elbow_hinge():
    """The layout's frames put the elbow's hinge where the ZEGGS BVH has it (same actor, same skeleton)."""
    bvh = read_bvh(shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"))
    s = bvh.skeleton
    _, euler = motion_to_euler(s, bvh.motion)
    G, P = global_transforms(s, local_matrices(s, euler))
    layout = load_layout("zeggs9")
    for take in TAKES:
        raw = load_array(shared_file(f"data/zeggs9/{take}.npy"), layout)
        S, pos = source_world(raw, layout)
        for side in ("Right", "Left"):
            ref = _hinge_axis(G[:, s.index(f"{side}Arm")], P[:, s.index(f"{side}Hand")] - P[:, s.index(f"{side}ForeArm")])
            got = _hinge_axis(S[f"{side}Arm"], pos[f"{side}Hand"] - pos[f"{side}ForeArm"])
            got = got if ref @ got > 0 else -got
            # the frames' twist about the bone (x in a BVH arm frame) is what a layout can get wrong
            twist = np.degrees(np.arctan2(got[2], got[1]) - np.arctan2(ref[2], ref[1]))
            assert abs((twist + 180) % 360 - 180) < 3.0, (take, side, twist)
            assert angles_deg(ref, got) < 6.0, (take, side)


def test_bad_arrays_are_refused(tmp_path, target):
    np.save(tmp_path / "wrong.npy", np.zeros((10, 8, 7)))
    with pytest.raises(UserError, match=r"\(T, 9, 7\)"):
        read_joints9(tmp_path / "wrong.npy", target)
    a = np.zeros((10, 9, 7))
    a[..., 3] = 1.0  # (x, y, z, w) = (1, 0, 0, 0) is unit; w first would be the same numbers: fine
    a[0, 0, 3:] = [0.5, 0.5, 0.5, 0.9]
    np.save(tmp_path / "norm.npy", a)
    with pytest.raises(UserError, match="unit length"):
        read_joints9(tmp_path / "norm.npy", target)
    (tmp_path / "obj.npy").write_bytes(b"\x93NUMPY\x01\x00v\x00{'descr': '|O', 'fortran_order': False, 'shape': (1,), }"
                                       + b" " * 60 + b"\n" + b"\x80\x04N.")
    with pytest.raises(UserError):
        read_joints9(tmp_path / "obj.npy", target)
