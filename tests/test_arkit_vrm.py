"""ARKit → VRM presets: names in the spelling the consumers match, and each preset driven by its action units."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.avatar.vrm.expressions import (
    PERFECT_SYNC_NAMES,
    VISEME_PROTOTYPES,
    VRM0_PRESETS,
    VRM1_EXPRESSIONS,
    viseme_solver,
    viseme_weights,
    vrm0_presets,
    vrm0_weights,
    vrm0_weights_array,
    vrm1_expressions,
)


def face(**weights) -> np.ndarray:
    w = np.zeros(52, np.float32)
    for name, v in weights.items():
        w[ARKIT_NAMES.index(name)] = v
    return w


def active(d: dict[str, float], eps: float = 0.05) -> set[str]:
    return {k for k, v in d.items() if v > eps}


def test_names():
    # UniVRM's VRM 0.x preset spelling; perfect-sync clips in UpperCamelCase
    assert {"Blink", "Blink_L", "Blink_R", "A", "I", "U", "E", "O", "Joy", "Angry", "Sorrow", "Fun"} <= set(VRM0_PRESETS)
    assert PERFECT_SYNC_NAMES[ARKIT_NAMES.index("eyeBlinkLeft")] == "EyeBlinkLeft"
    assert PERFECT_SYNC_NAMES[ARKIT_NAMES.index("jawOpen")] == "JawOpen"
    assert PERFECT_SYNC_NAMES[-1] == "TongueOut" and len(set(PERFECT_SYNC_NAMES)) == 52
    assert {"aa", "ih", "ou", "ee", "oh", "blink", "blinkLeft", "blinkRight", "happy", "sad", "relaxed"} \
        <= set(VRM1_EXPRESSIONS)


def test_neutral_face_sends_nothing():
    assert not active(vrm0_presets(face()), 1e-9)


def test_blink_split_keeps_each_eyelid_exact():
    p = vrm0_presets(face(eyeBlinkLeft=0.9, eyeBlinkRight=0.4))
    assert p["Blink"] == pytest.approx(0.4) and p["Blink_L"] == pytest.approx(0.5) and p["Blink_R"] == 0
    # an avatar adds Blink (both lids) and Blink_L/R (one lid each)
    assert p["Blink"] + p["Blink_L"] == pytest.approx(0.9) and p["Blink"] + p["Blink_R"] == pytest.approx(0.4)


@pytest.mark.parametrize("shape, vowel", [
    (dict(jawOpen=0.7, mouthLowerDownLeft=0.3, mouthLowerDownRight=0.3), "A"),
    (dict(jawOpen=0.15, mouthStretchLeft=0.5, mouthStretchRight=0.5, mouthUpperUpLeft=0.3,
          mouthUpperUpRight=0.3), "I"),
    (dict(jawOpen=0.1, mouthPucker=0.8, mouthFunnel=0.3), "U"),
    (dict(jawOpen=0.35, mouthStretchLeft=0.3, mouthStretchRight=0.3, mouthLowerDownLeft=0.35,
          mouthLowerDownRight=0.35), "E"),
    (dict(jawOpen=0.45, mouthFunnel=0.7, mouthPucker=0.3), "O"),
])
def test_visemes_from_mouth_shapes(shape, vowel):
    p = vrm0_presets(face(**shape))
    vis = {k: p[k] for k in "AIUEO"}
    assert max(vis, key=vis.get) == vowel and vis[vowel] > 0.6
    assert sum(vis.values()) <= 1.0 + 1e-9


def test_lips_closed_over_open_jaw_is_no_viseme():
    p = vrm0_presets(face(jawOpen=0.5, mouthClose=0.5))
    assert max(p[k] for k in "AIUEO") < 0.02


def test_emotions():
    assert active(vrm0_presets(face(mouthSmileLeft=0.8, mouthSmileRight=0.8))) == {"Fun"}
    assert active(vrm0_presets(face(mouthSmileLeft=0.8, mouthSmileRight=0.8, cheekSquintLeft=0.6,
                                    cheekSquintRight=0.6))) == {"Joy"}
    assert active(vrm0_presets(face(browDownLeft=0.8, browDownRight=0.8, eyeSquintLeft=0.5,
                                    eyeSquintRight=0.5))) == {"Angry"}
    # one action unit alone is not an emotion: speech moves brows and lip corners
    assert not active(vrm0_presets(face(browDownLeft=0.8, browDownRight=0.8)), 1e-9)
    assert not active(vrm0_presets(face(browInnerUp=0.9)), 1e-9)
    assert not active(vrm0_presets(face(mouthFrownLeft=0.9, mouthFrownRight=0.9)), 1e-9)
    assert not active(vrm0_presets(face(mouthSmileLeft=0.9)), 1e-9)  # a one-sided smirk
    assert active(vrm0_presets(face(browInnerUp=0.8, mouthFrownLeft=0.7, mouthFrownRight=0.7))) == {"Sorrow"}
    assert "Surprised" in active(vrm0_presets(face(eyeWideLeft=0.8, eyeWideRight=0.8, browOuterUpLeft=0.7,
                                                   browOuterUpRight=0.7)))
    # a tracker's small resting values stay at 0
    assert not active(vrm0_presets(face(mouthSmileLeft=0.15, browDownLeft=0.15, browDownRight=0.15)), 1e-9)


def test_eye_look_sides():
    p = vrm0_presets(face(eyeLookOutLeft=0.6, eyeLookInRight=0.6))
    assert p["LookLeft"] == pytest.approx(0.6) and p["LookRight"] == 0


def test_batched_equals_per_frame_and_vrm1():
    rng = np.random.default_rng(0)
    w = rng.uniform(0, 1, (7, 52))
    batch = vrm0_weights(w)
    assert batch.shape == (7, len(VRM0_PRESETS)) and ((batch >= 0) & (batch <= 1)).all()
    np.testing.assert_allclose(batch[3], list(vrm0_presets(w[3]).values()))
    assert list(vrm1_expressions(w[3]).values()) == pytest.approx(batch[3].tolist())
    with pytest.raises(ValueError):
        vrm0_weights(w[:, :51])


def test_compiled_presets_are_the_array_path_to_the_bit():
    """The compiled presets (one frame, a VMC tick's, and batches; issue 36) give the bytes of the NumPy form, on
    random frames and on frames made of the ramps' bounds, 0, −0, 1 and out-of-range values; weights that are not
    finite take the NumPy form."""
    rng = np.random.default_rng(3)
    edges = np.array([0.0, -0.0, 1.0, 0.3, 0.7, 0.15, 0.5, 0.2, 1e-4, -0.2, 1.3])
    frames = [rng.uniform(0, 1, 52), np.zeros(52), np.full(52, -0.0), (rng.random(52) ** 3).astype(np.float32)]
    frames += [np.where(rng.random(52) < 0.5, rng.choice(edges, 52), rng.random(52)) for _ in range(3000)]
    for f in frames:
        assert vrm0_weights(f).tobytes() == vrm0_weights_array(f).tobytes()
    batch = np.array(frames[4:]).reshape(2, -1, 52)
    assert vrm0_weights(batch).tobytes() == vrm0_weights_array(batch).tobytes()
    nan = np.full(52, 0.5)
    nan[0] = np.nan  # not finite: the array path
    assert vrm0_weights(nan).tobytes() == vrm0_weights_array(nan).tobytes() == vrm0_weights(nan[None])[0].tobytes()
    assert np.isnan(vrm0_weights(nan)[VRM0_PRESETS.index("Angry")])  # browDownLeft NaN: as NumPy gives it
    mouth_nan = face(jawOpen=0.5).astype(np.float64)
    mouth_nan[ARKIT_NAMES.index("mouthFunnel")] = np.nan
    assert not vrm0_weights(mouth_nan)[3:8].any()  # a NaN mouth feature: no viseme, as before


def _scipy_visemes(features: np.ndarray) -> np.ndarray:
    from scipy.optimize import nnls

    out = np.zeros((len(features), 5))
    for k, f in enumerate(features):
        out[k] = nnls(VISEME_PROTOTYPES.T, f)[0]
    return out


def _nnls(features: np.ndarray) -> np.ndarray:
    kernels, A, pinv, _ = viseme_solver()
    out = np.zeros((len(features), 5))
    for k, f in enumerate(features):
        kernels.nnls(A, pinv, np.ascontiguousarray(f, np.float64), out[k])
    return out


def test_nnls_is_scipys_solution_and_meets_kkt():
    """The exact 5-unknown solve (every passive set) is SciPy's Lawson–Hanson solution to ~1e-15, and meets the
    KKT conditions: x ≥ 0, no gradient where x > 0, none pointing into x < 0 where x = 0."""
    rng = np.random.default_rng(7)
    feats = np.concatenate([
        rng.uniform(0, 1, (3000, 6)),
        rng.uniform(0, 1, (1000, 6)) ** 4 * (rng.random((1000, 6)) < 0.5),  # sparse: exact zeros
        rng.uniform(0, 1, (500, 5)) @ VISEME_PROTOTYPES,  # inside the cone: exact fits
        np.eye(6), VISEME_PROTOTYPES, np.zeros((1, 6)),
    ])  # fmt: skip
    x, ref = _nnls(feats), _scipy_visemes(feats)
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-12)
    A = VISEME_PROTOTYPES.T
    grad = (feats - x @ A.T) @ A  # Aᵀ(f − Ax): the objective's descent direction per unknown
    assert (x >= 0).all()
    assert np.abs(np.where(x > 0, grad, 0)).max() < 1e-12
    assert np.where(x == 0, grad, 0).max() < 1e-12
    np.testing.assert_allclose(_nnls(VISEME_PROTOTYPES), np.eye(5), atol=1e-14)  # a vowel's own prototype
    assert not _nnls(np.zeros((1, 6))).any()


def test_visemes_keep_their_rules():
    """Below 1e-4 everywhere or NaN: no viseme; each weight ≤ 1 and their sum ≤ 1 (scaled, not clipped)."""
    kernels, A, pinv, _ = viseme_solver()
    feats = np.array([np.full(6, 1e-4), np.full(6, 0.9), [np.nan, 0.5, 0.5, 0.5, 0.5, 0.5], VISEME_PROTOTYPES[0]])
    out = np.empty((len(feats), 5))
    kernels.visemes(A, pinv, feats, out)
    assert not out[[0, 2]].any()
    assert out[1].sum() == pytest.approx(1.0) and (out <= 1).all()
    np.testing.assert_allclose(out[3], [1, 0, 0, 0, 0], atol=1e-14)
    clipped = np.minimum(_nnls(feats[1:2])[0], 1.0)
    assert clipped.sum() > 1.0
    np.testing.assert_allclose(out[1], clipped / clipped.sum(), rtol=1e-15)
    w = np.random.default_rng(1).uniform(0, 1, (4, 3, 52))
    assert viseme_weights(w).shape == (4, 3, 5)


def test_real_iphone_face_blinks_are_exact():
    """On a real ARKit face (the Live Link recording), the blink split reproduces each eyelid in every frame."""
    import gzip
    import struct

    from conftest import shared_file
    from facecapges.runtime.inputs.livelink import decode_packet

    raw = gzip.decompress(shared_file("data/livelink/dao.gesichter").read_bytes())
    pos, W = 5, []
    for _ in range(struct.unpack_from(">I", raw, 1)[0]):
        (n,) = struct.unpack_from(">I", raw, pos)
        W.append(decode_packet(raw[pos + 4:pos + 4 + n]).weights52)
        pos += 4 + n
    W = np.array(W)
    P = dict(zip(VRM0_PRESETS, vrm0_weights(W).T))
    np.testing.assert_allclose(P["Blink"] + P["Blink_L"], W[:, ARKIT_NAMES.index("eyeBlinkLeft")], atol=1e-6)
    np.testing.assert_allclose(P["Blink"] + P["Blink_R"], W[:, ARKIT_NAMES.index("eyeBlinkRight")], atol=1e-6)
    assert P["Blink"].max() > 0.8  # the recording blinks
    vis = np.stack([P[v] for v in "AIUEO"], -1)
    assert vis.sum(-1).max() <= 1.0 + 1e-9 and vis.max() > 0.4  # the mouth moves, never over-opened
