"""Mirroring (twice = identity, FK reflected) and masked training losses (missing joints add nothing)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import shared_file
from facecapges import rotations as rot
from facecapges.arkit import ARKIT_NAMES
from facecapges.data.mirror import REFLECT, mirror_face, mirror_mask, mirror_pose, mirror_rot6d, mirror_rotations
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY, joint_positions, motion_to_pose, pose_to_motion
from facecapges.training.masking import discriminator_view, masked_reconstruction_losses, mirrored
from facecapges.training.segments import ClipArrays, SegmentSet
from facecapges.training.train import reconstruction_losses


@pytest.fixture(scope="module")
def beat():
    return read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))


def test_rot6d_mirror_is_the_matrix_conjugation():
    R = rot.euler_to_matrix(np.random.default_rng(0).normal(size=(20, 3)), "XYZ")
    assert np.allclose(mirror_rot6d(rot.matrix_to_rot6d(R)), rot.matrix_to_rot6d(mirror_rotations(R)))


def test_mirror_twice_is_identity(beat):
    pose, _head = motion_to_pose(beat.skeleton, beat.motion)
    assert np.array_equal(mirror_pose(mirror_pose(pose)), pose)
    face = np.random.default_rng(1).random((5, 52)).astype(np.float32)
    assert np.array_equal(mirror_face(mirror_face(face)), face)
    assert not np.array_equal(mirror_pose(pose), pose)


def test_mirrored_fk_is_the_reflected_fk(beat):
    skel = beat.skeleton
    pose, _ = motion_to_pose(skel, beat.motion[::10])
    P = joint_positions(skel, pose_to_motion(skel, pose))
    Pm = joint_positions(skel, pose_to_motion(skel, mirror_pose(pose)))
    twin = [skel.index(n.replace("Right", "#").replace("Left", "Right").replace("#", "Left")) for n in skel.names]
    reflected = P @ REFLECT  # x → −x (REFLECT is symmetric)
    err = np.linalg.norm(Pm[:, twin] - reflected, axis=-1)
    # BEAT's skeleton is left/right symmetric to ~0.1 cm; arms reach ~75 cm from the spine
    assert err.max() < 0.5, err.max()
    assert np.linalg.norm(P[:, twin] - reflected, axis=-1).max() > 10  # and the motion is not symmetric itself


def test_mirror_swaps_face_and_mask():
    f = np.zeros(52)
    f[ARKIT_NAMES.index("eyeBlinkLeft")] = 1
    f[ARKIT_NAMES.index("jawRight")] = 0.5
    g = mirror_face(f)
    assert g[ARKIT_NAMES.index("eyeBlinkRight")] == 1 and g[ARKIT_NAMES.index("jawLeft")] == 0.5
    m = np.array([n.startswith("Right") for n in UPPER_BODY])
    assert np.array_equal(mirror_mask(m), np.array([n.startswith("Left") for n in UPPER_BODY]))


def test_masked_loss_ignores_missing_joints():
    g = torch.Generator().manual_seed(0)
    gen, gt = torch.randn(4, 18, 47 * 6, generator=g), torch.randn(4, 18, 47 * 6, generator=g)
    ones = torch.ones(4, 18, 47)
    plain = reconstruction_losses(gen, gt, 0.1)
    for k, v in masked_reconstruction_losses(gen, gt, 0.1, ones).items():
        assert torch.allclose(v, plain[k]), k
    mask = ones.clone()
    mask[:, :, 20:] = 0  # joints 20… missing
    base = masked_reconstruction_losses(gen, gt, 0.1, mask)
    changed = gen.clone()
    changed[..., 20 * 6:] += 100.0  # whatever the generator does there
    for k, v in masked_reconstruction_losses(changed, gt, 0.1, mask).items():
        assert torch.allclose(v, base[k]), k
    x = gen.clone().requires_grad_(True)
    sum(masked_reconstruction_losses(x, gt, 0.1, mask).values()).backward()
    assert x.grad[..., 20 * 6:].abs().max() == 0 and x.grad[..., :20 * 6].abs().max() > 0
    # the discriminator sees the real values at masked joints, and no gradient flows there
    y = gen.clone().requires_grad_(True)
    view = discriminator_view(y, gt, mask)
    assert torch.equal(view[..., 20 * 6:], gt[..., 20 * 6:]) and torch.equal(view[..., :20 * 6], gen[..., :20 * 6])
    view.sum().backward()
    assert y.grad[..., 20 * 6:].abs().max() == 0


def test_batches_carry_the_mask_and_mirrored_clips():
    from facecapges.network.config import ModelConfig

    T = 60
    rng = np.random.default_rng(0)
    mask = np.array([n in ("Spine", "RightArm") for n in UPPER_BODY])
    clip = ClipArrays("c", rng.normal(size=(T, 47, 6)).astype(np.float32), np.zeros((T, 6), np.float32),
                      np.zeros((T, 52), np.float32), np.zeros(T * 1067, np.float32), mask=mask)
    cfg = ModelConfig()
    seg = SegmentSet([clip, mirrored(clip)], cfg, 34, 10)
    b = seg.gather(np.arange(len(seg)))
    assert b["mask"].shape == (len(seg), 34, 47)
    first, last = b["mask"][0, 0].bool().numpy(), b["mask"][-1, 0].bool().numpy()
    assert np.array_equal(first, mask) and np.array_equal(last, mirror_mask(mask))
    assert last[UPPER_BODY.index("LeftArm")] and not last[UPPER_BODY.index("RightArm")]


def test_a_take_and_a_training_clip_share_one_statement_of_their_arrays():
    """The matching engine's Take and the trainer's ClipArrays are both FrameArrays: one shape check (a face of
    the wrong length is a clear UserError naming the take, for either) and one mirror image."""
    from facecapges.data.cache import FrameArrays
    from facecapges.errors import UserError
    from facecapges.matching.takes import Take, make_take, mirror_take
    from facecapges.skeleton import Skeleton

    assert issubclass(Take, FrameArrays) and issubclass(ClipArrays, FrameArrays)
    T, rng = 40, np.random.default_rng(1)
    pose = rot.identity_rot6d((T, 47)).astype(np.float32) + rng.normal(0, 0.05, (T, 47, 6)).astype(np.float32)
    head, face = np.zeros((T, 6), np.float32), rng.uniform(size=(T, 52)).astype(np.float32)
    with pytest.raises(UserError, match=r"short: face has shape \(39, 52\)"):
        ClipArrays("short", pose, head, face[:-1], np.zeros(T * 1067, np.float32))
    skel = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh")).skeleton
    assert isinstance(skel, Skeleton)
    take = make_take("t", pose, np.zeros(T * 1067, np.float32), skel, face=face, head=head)
    with pytest.raises(UserError, match="t: head has shape"):
        Take(**{**vars(take), "head": head[:, :3]})
    clip = ClipArrays("t", take.pose, take.head, take.face, take.audio)
    a, b = mirror_take(take), mirrored(clip)
    assert a.name == b.name == "t~mirror" and a.mirrored and a.n_frames == b.n_frames == T
    for key in ("pose", "head", "face", "audio"):
        assert np.array_equal(getattr(a, key), getattr(b, key)) and getattr(a, key).dtype == np.float32
