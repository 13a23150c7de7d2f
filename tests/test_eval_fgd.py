"""FGD: graph, Fréchet distance numerics, autoencoder training on the real clip, save/load."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from facecapges import rotations as rot
from facecapges.errors import UserError
from facecapges.evaluation import fgd as F
from facecapges.evaluation.regions import region_joints
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY, motion_to_pose


@pytest.fixture(scope="module")
def real_pose():
    from conftest import shared_file

    bvh = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    return bvh.skeleton, motion_to_pose(bvh.skeleton, bvh.motion)[0]


# ----------------------------------------------------------------------- graph
def test_parent_table_matches_the_real_beat_hierarchy(real_pose):
    skel, _ = real_pose
    assert F.parents_within(skel) == F.UPPER_BODY_PARENT
    assert F.UPPER_BODY_PARENT["Neck"] == "Spine" and F.UPPER_BODY_PARENT["RightShoulder"] == "Spine"
    assert F.UPPER_BODY_PARENT["LeftHandThumb1"] == "LeftHandIndex"


@pytest.mark.parametrize("region", ["with_head", "without_head"])
def test_adjacency_is_a_tree_with_self_loops(region):
    names = region_joints(region)
    A = F.adjacency(names)
    J = len(names)
    assert A.shape == (J, J) and np.array_equal(A, A.T) and np.all(np.diag(A) == 1)
    assert A.sum() == J + 2 * (J - 1)  # self-loops + both directions of J-1 tree edges
    reach = np.eye(J, dtype=bool)  # connected: everything reachable within J steps
    for _ in range(J):
        reach = (reach.astype(np.float64) @ A) > 0
    assert reach.all()


def test_adjacency_skips_removed_joints():
    A = F.adjacency(["Spine", "Neck1", "RightArm", "RightShoulder"])
    # Neck1's parent Neck is absent → attaches to Spine; RightArm → RightShoulder → Spine
    assert A[0, 1] == 1 and A[2, 3] == 1 and A[3, 0] == 1 and A[1, 2] == 0


def test_graph_layer_is_eq_5_7_for_kernel_1():
    A = torch.from_numpy(F.adjacency(["Spine", "Neck", "Neck1"]))
    layer = F.GraphConv(A, 2, 3, kernel=1)
    torch.nn.init.normal_(layer.b)
    x = torch.randn(1, 2, 1, 3)  # (B, C, T, J)
    W = layer.W.weight[:, :, 0, 0]  # (3, 2)
    h = x[0, :, 0, :]  # (C, J)
    expect = torch.tanh(torch.stack([sum(A[i, j] * (W @ h[:, j]) for j in range(3)) + layer.b for i in range(3)], 1))
    assert torch.allclose(layer(x)[0, :, 0, :], expect, atol=1e-6)


# -------------------------------------------------------------- Fréchet distance
def test_frechet_distance_hand_computed_1d_and_diagonal():
    # N(0, 1) vs N(1, 4): 1 + 1 + 4 - 2·sqrt(4) = 2
    assert F.frechet_distance([0.0], [[1.0]], [1.0], [[4.0]]) == pytest.approx(2.0)
    mu1, mu2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    v1, v2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 0.0])
    expect = np.sum((mu1 - mu2) ** 2) + np.sum((np.sqrt(v1) - np.sqrt(v2)) ** 2)
    for method in ("eigh", "sqrtm"):
        assert F.frechet_distance(mu1, np.diag(v1), mu2, np.diag(v2), method=method) == pytest.approx(expect)


def test_frechet_methods_agree_on_well_conditioned_covariances():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(400, 8)), rng.normal(size=(300, 8)) @ rng.normal(size=(8, 8)) + 0.5
    d1 = F.frechet_distance_features(a, b, method="eigh")
    d2 = F.frechet_distance_features(a, b, method="sqrtm")
    assert d1 == pytest.approx(d2, rel=1e-6)
    assert F.frechet_distance_features(b, a) == pytest.approx(d1, rel=1e-6)  # symmetric


@pytest.mark.parametrize("method", ["eigh", "sqrtm"])
def test_frechet_rank_deficient_covariances_give_finite_real_values(method):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(10, 128))  # 10 samples in 128 dims: rank 9
    y = rng.normal(size=(7, 128)) * 0.5
    const = np.ones((5, 128))  # zero covariance
    same = F.frechet_distance_features(x, x, method=method)
    assert isinstance(same, float) and np.isfinite(same) and 0.0 <= same < 1e-6
    d = F.frechet_distance_features(x, y, method=method)
    assert isinstance(d, float) and np.isfinite(d) and d > 0
    mu = x.mean(0)
    dc = F.frechet_distance_features(const, const[:3] + 1.0, method=method)
    assert dc == pytest.approx(128.0)  # only the means differ, by 1 in every dimension
    # near-singular: one dimension with variance 1e-14
    s = np.diag(np.r_[np.ones(5), 1e-14])
    assert np.isfinite(F.frechet_distance(mu[:6], s, mu[:6], s, method=method))
    assert F.frechet_distance(mu[:6], s, mu[:6], s, method=method) < 1e-6


def test_frechet_rejects_shape_mismatch():
    with pytest.raises(ValueError):
        F.frechet_distance(np.zeros(2), np.eye(2), np.zeros(3), np.eye(3))


# ---------------------------------------------------------------- windows, model
def test_windows_32_frames_stride_10(real_pose):
    _, pose = real_pose
    w = F.make_windows([pose, pose[:31]], 32, 10)
    assert w.shape == ((957 - 32) // 10 + 1, 32, 47, 6)
    assert np.array_equal(w[3], pose[30:62])
    assert F.make_windows([pose[:20]]).shape[0] == 0


def test_autoencoder_shapes():
    cfg = F.FGDConfig()
    m = F.FGDAutoencoder(cfg, UPPER_BODY)
    x = torch.randn(2, 32, 47, 6)
    assert m.encode(x).shape == (2, 8, 128)
    assert m(x).shape == x.shape
    with pytest.raises(ValueError):
        F.FGDConfig(window=30)


def test_velocity_term_of_the_loss():
    x = torch.zeros(1, 4, 1, 6)
    offset = torch.full_like(x, 0.5)  # constant offset: position error only
    assert F.reconstruction_loss(x + offset, x).item() == pytest.approx(0.25)
    ramp = torch.arange(4.0).reshape(1, 4, 1, 1).expand(1, 4, 1, 6)  # velocity error 1 everywhere
    assert F.reconstruction_loss(ramp, x, 0.0, 0.1).item() == pytest.approx(0.1)


@pytest.mark.slow
def test_training_on_the_real_clip_lowers_the_loss_and_scores_gt_as_zero(real_pose, tmp_path):
    _skel, pose = real_pose
    cfg = F.FGDConfig(epochs=4)
    ev = F.train_fgd([pose[:766]], cfg, regions=("with_head",), progress=False)
    loss = ev.history.loss["with_head"]
    assert len(loss) == 4 and loss[-1] < loss[0]
    test = pose[766:]
    gt = ev.fgd([test], [test], "with_head")
    assert 0.0 <= gt < 1e-3
    still = np.repeat(test[:1], len(test), 0)
    assert ev.fgd([test], [still], "with_head") > 100 * max(gt, 1e-9)
    rng = np.random.default_rng(0)
    noisy = [rot.normalize_rot6d(test + rng.normal(0, s, test.shape)).astype(np.float32) for s in (0.03, 0.3)]
    assert gt < ev.fgd([test], [noisy[0]], "with_head") < ev.fgd([test], [noisy[1]], "with_head")
    # save next to a checkpoint and load back: same features
    ckpt = tmp_path / "model.safetensors"
    w, c = F.save_fgd(ev, ckpt)
    assert (w, c) == (tmp_path / "model.fgd" / "fgd_autoencoder.safetensors", tmp_path / "model.fgd" /
                      "fgd_autoencoder.json") and not ckpt.exists()
    assert F.fgd_paths(tmp_path) == (tmp_path / "fgd_autoencoder.safetensors", tmp_path / "fgd_autoencoder.json")
    back = F.load_fgd(ckpt)
    assert back.config == ev.config and back.regions == ["with_head"]
    assert back.history.loss["with_head"] == pytest.approx(loss)
    np.testing.assert_allclose(back.embed([test], "with_head"), ev.embed([test], "with_head"), atol=1e-6)
    with pytest.raises(KeyError):
        back.embed([test], "without_head")


def test_load_missing_fgd_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="not found"):
        F.load_fgd(tmp_path)
