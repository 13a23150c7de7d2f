"""Evaluation regions and the reference rows."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.evaluation import baselines as bl
from facecapges.evaluation.regions import region_indices, region_joints, select
from facecapges.skeleton import HEAD_REGION, UPPER_BODY


def test_regions():
    assert region_joints("with_head") == UPPER_BODY
    wo = region_joints("without_head")
    assert len(wo) == 45 and "Neck" not in wo and "Neck1" not in wo and set(HEAD_REGION) == {"Neck", "Neck1"}
    pose = np.arange(47 * 6, dtype=np.float32).reshape(1, 47, 6).repeat(3, 0)
    s = select(pose, "without_head")
    assert s.shape == (3, 45, 6) and np.array_equal(s[:, 0], pose[:, 0]) and np.array_equal(s[:, 1], pose[:, 3])
    assert region_indices("with_head").tolist() == list(range(47))
    with pytest.raises(ValueError):
        region_joints("head_only")
    with pytest.raises(ValueError):
        select(np.zeros((3, 46, 6)), "with_head")


def test_mean_pose_is_valid_and_static():
    rng = np.random.default_rng(0)
    clips = [rot.normalize_rot6d(rng.normal(size=(20, 47, 6))), rot.normalize_rot6d(rng.normal(size=(7, 47, 6)))]
    seq = bl.mean_pose_sequence(clips, 11)
    assert seq.shape == (11, 47, 6) and np.all(seq == seq[0])
    R = rot.rot6d_to_matrix(seq[0].astype(np.float64))
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
    same = [np.repeat(clips[0][:1], 5, 0)]  # mean of one repeated pose is that pose
    np.testing.assert_allclose(bl.mean_pose(same), clips[0][0], atol=1e-6)


def test_random_segment_avoids_the_evaluated_interval():
    clip = np.arange(100, dtype=np.float32)[:, None, None] * np.ones((1, 47, 6), np.float32)
    for seed in range(20):
        seg = bl.random_segment([clip], 20, seed, exclude=(0, 40, 100))
        start = int(seg[0, 0, 0])
        assert seg.shape == (20, 47, 6) and start + 20 <= 40
    with pytest.raises(ValueError):
        bl.random_segment([clip], 70, 0, exclude=(0, 30, 100))
    gt = bl.ground_truth(clip)
    assert gt is not clip and np.array_equal(gt, clip)
