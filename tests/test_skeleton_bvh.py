"""BVH reading/writing, forward kinematics, head rotation and pose conversion on the real sample."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecapges import rotations as rot
from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.skeleton import (
    N_JOINTS,
    UPPER_BODY,
    global_transforms,
    joint_positions,
    local_matrices,
    motion_to_euler,
    motion_to_pose,
    pose_to_motion,
    rest_positions,
)


@pytest.fixture(scope="module")
def sample(request):
    from conftest import shared_file

    return read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))


def test_sample_header(sample):
    skel = sample.skeleton
    assert skel.n_joints == 75 and skel.n_channels == 228
    assert sample.n_frames == 957 and sample.fps == 15.0
    assert skel.names[0] == "Hips" and skel.parents[0] == -1 and len(skel.channels[0]) == 6
    assert skel.missing(UPPER_BODY) == []
    assert skel.chain_to("Head")[-3:] == [skel.index("Neck"), skel.index("Neck1"), skel.index("Head")]
    # only the 47 upper-body joints move (the README's description of the sample)
    _, euler = motion_to_euler(skel, sample.motion)
    moving = {skel.names[j] for j in range(skel.n_joints) if np.abs(euler[:, j]).max() > 0}
    assert moving <= set(UPPER_BODY) and len(moving) >= 40


def test_rest_positions_are_the_forward_kinematics_of_the_rest_pose(sample):
    skel = sample.skeleton
    eye = np.broadcast_to(np.eye(3), (1, skel.n_joints, 3, 3)).copy()
    P = rest_positions(skel)
    assert P.shape == (75, 3)
    np.testing.assert_allclose(P, global_transforms(skel, eye)[1][0], atol=1e-12)
    head, neck1 = skel.index("Head"), skel.index("Neck1")
    np.testing.assert_allclose(P[head] - P[neck1], skel.offsets[head])  # a child sits at its offset from its parent


def test_write_read_round_trip(sample, tmp_path):
    path = write_bvh(tmp_path / "rt.bvh", sample.skeleton, sample.motion, sample.fps)
    again = read_bvh(path)
    assert again.skeleton.is_same_tree(sample.skeleton)
    assert again.skeleton.channels == sample.skeleton.channels
    np.testing.assert_allclose(again.skeleton.offsets, sample.skeleton.offsets, atol=1e-6)
    assert again.skeleton.end_sites.keys() == sample.skeleton.end_sites.keys()
    np.testing.assert_allclose(again.motion, sample.motion, atol=5e-7)
    assert again.fps == sample.fps
    assert not list(tmp_path.glob("*.part"))  # written atomically


def test_motion_text_is_each_values_own_format(sample, tmp_path):
    """Columns at rest (+0.0 in every row) are written as a literal: the text stays f"{v:.6f}" of every value,
    also for −0.0, NaN, ±inf and a column that is zero in some rows only."""
    m = np.array(sample.motion[:6], np.float64)
    m[:, 1], m[:, 2], m[:3, 3], m[:, 4] = 0.0, -0.0, 0.0, np.nan
    m[0, 5], m[1, 6] = np.inf, -np.inf
    path = write_bvh(tmp_path / "text.bvh", sample.skeleton, m, sample.fps)
    rows = path.read_text(encoding="utf-8").splitlines()[-len(m) :]
    assert rows == [" ".join(f"{v:.6f}" for v in row) for row in m.tolist()]


def test_fk_rest_pose_and_rigid_bones(sample):
    skel = sample.skeleton
    # rest pose: positions are the summed offsets along each chain
    rest = joint_positions(skel, np.zeros((1, skel.n_channels)))[0]
    for j in range(skel.n_joints):
        np.testing.assert_allclose(rest[j], skel.offsets[skel.chain_to(skel.names[j])].sum(0), atol=1e-9)
    # animated: every bone keeps its length in every frame
    pos = joint_positions(skel, sample.motion)
    for j in range(1, skel.n_joints):
        lengths = np.linalg.norm(pos[:, j] - pos[:, skel.parents[j]], axis=-1)
        np.testing.assert_allclose(lengths, np.linalg.norm(skel.offsets[j]), atol=1e-9)


def test_fk_matches_an_independent_chain_product(sample):
    """RightHand's position from scipy rotations chained by hand, on a few frames."""
    skel = sample.skeleton
    _, euler = motion_to_euler(skel, sample.motion)
    pos = joint_positions(skel, sample.motion)
    chain = skel.chain_to("RightHand")
    for t in (0, 400, 956):
        G = Rotation.identity()
        p = np.zeros(3)
        for k, j in enumerate(chain):
            p = p + (G.apply(skel.offsets[j]) if k else skel.offsets[j])
            G = G * Rotation.from_euler(skel.rotation_order(j), euler[t, j], degrees=True)
        np.testing.assert_allclose(pos[t, chain[-1]], p, atol=1e-9)


def test_head_rot6d_is_the_chained_product(sample):
    skel = sample.skeleton
    _, euler = motion_to_euler(skel, sample.motion)
    pose, head = motion_to_pose(skel, sample.motion)
    assert pose.shape == (957, N_JOINTS, 6) and head.shape == (957, 6)
    assert pose.dtype == np.float32 and head.dtype == np.float32
    mats = local_matrices(skel, euler)
    expected = np.broadcast_to(np.eye(3), (957, 3, 3))
    for j in skel.chain_to("Head"):
        expected = expected @ mats[:, j]
    np.testing.assert_allclose(head, rot.matrix_to_rot6d(expected), atol=1e-6)
    # the sample carries no Head motion: it is the global rotation of the end of the neck chain
    G, _ = global_transforms(skel, mats)
    np.testing.assert_allclose(head, rot.matrix_to_rot6d(G[:, skel.index("Neck1")]), atol=1e-6)
    # and the head does turn in this clip
    assert np.degrees(rot.geodesic_angle(rot.rot6d_to_matrix(head[:1]), rot.rot6d_to_matrix(head))).max() > 5


def test_pose_round_trip_keeps_joint_positions(sample):
    skel = sample.skeleton
    pose, _ = motion_to_pose(skel, sample.motion)
    motion = pose_to_motion(skel, pose)
    assert motion.shape == sample.motion.shape
    np.testing.assert_allclose(joint_positions(skel, motion), joint_positions(skel, sample.motion), atol=1e-3)
    # the written angles are unwrapped: no ±360° jumps left for interpolating players
    assert np.abs(np.diff(motion, axis=0)).max() < 180


def test_bvh_errors_name_the_file(sample, tmp_path, beat_bvh):
    text = beat_bvh.read_text()
    cut = tmp_path / "cut.bvh"
    cut.write_text(text[: len(text) // 2])
    with pytest.raises(UserError, match=r"cut\.bvh.*truncated"):
        read_bvh(cut)
    head = tmp_path / "head.bvh"
    head.write_text(text[: text.index("MOTION") - 200])
    with pytest.raises(UserError, match=r"head\.bvh.*truncated"):
        read_bvh(head)
    with pytest.raises(UserError, match="not found"):
        read_bvh(tmp_path / "missing.bvh")
    junk = tmp_path / "junk.bvh"
    junk.write_text("hello\n")
    with pytest.raises(UserError, match=r"junk\.bvh.*not a BVH"):
        read_bvh(junk)


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("fps", [15.0, 4.0])
def test_the_recorder_writes_each_second_as_the_writer_did(sample, tmp_path, fps, compiled):
    """``live``'s BVH recorder converts and writes a second over the next second's frames (a step a frame): the same
    file as each second written at once (its Euler angles unwrapped within the second), a second behind while it
    records; at 4 fps a second is shorter than its steps (finished when the next one is full); a last part second."""
    from facecapges.io.bvh import BvhWriter
    from facecapges.rotations import normalize_rot6d
    from facecapges.runtime.outputs.recorders import BvhRecorder

    class Frame:
        def __init__(self, pose):
            self.pose = pose

    rng = np.random.default_rng(0)
    poses = motion_to_pose(sample.skeleton, sample.motion[:100])[0].astype(np.float32)
    poses[40:50] += rng.standard_normal(poses[40:50].shape).astype(np.float32)  # not orthonormal: normalised
    poses[60:70, 5] = -poses[60:70, 5]  # jumps past 180°: unwrapped within the second
    block = max(1, round(fps))
    with BvhWriter(tmp_path / "want.bvh", sample.skeleton, None, fps) as w:
        for i in range(0, len(poses), block):
            w.write(pose_to_motion(sample.skeleton, normalize_rot6d(poses[i : i + block].astype(np.float64))))
            w.flush()
    rec = BvhRecorder(tmp_path / "got.bvh", sample.skeleton, fps, compiled=compiled)
    for k, p in enumerate(poses):
        rec.write(Frame(p))
        if fps == 15.0 and k == block:  # the first second full, its steps to come: no file of no frame yet
            assert not (tmp_path / "got.bvh").exists()
        if fps == 15.0 and k == 2 * block - 1:  # the first second on disk, the second one not yet
            assert read_bvh(tmp_path / "got.bvh").motion.shape[0] == block
    rec.close()
    assert (tmp_path / "got.bvh").read_bytes() == (tmp_path / "want.bvh").read_bytes()


def test_the_compiled_motion_text_is_percent_formats():
    """:mod:`facecapges.io.bvh_text` writes ``"%.6f" % v`` of every value: 2 million of every scale, ties in
    binary (``k + 0.5`` millionths), values rounded to 5–7 decimals, signed zeros, tiny negatives, huge ones, NaN and
    infinities (a row with one of those is written by ``%`` itself)."""
    from facecapges.io import bvh_text

    rng = np.random.default_rng(11)
    for i in range(40):
        m = rng.standard_normal((50, 1000)) * 10.0 ** rng.uniform(-9, 5, (50, 1000))
        if i % 4 == 1:
            m = np.round(m, int(rng.integers(5, 8)))
        elif i % 4 == 2:
            m = (rng.integers(-(10**10), 10**10, (50, 1000)) + 0.5) / 1e6
        elif i % 4 == 3:
            m[:, ::7] = rng.choice([0.0, -0.0, -1e-9, 5e-7, -5e-7, 1e15, np.nan, np.inf, -np.inf, 180.0], (50, 143))
        want = [" ".join([f"{v:.6f}" for v in row]) for row in m.tolist()]
        assert bvh_text.motion_lines(m) == want
    assert bvh_text.motion_lines(np.zeros((0, 5))) == []
