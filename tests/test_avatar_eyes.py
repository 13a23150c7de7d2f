"""The avatar's eyes and jaw line: eyeballs that follow eyeLook*, blinks that cover them, no seam."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.avatar.body import PUPIL, SCLERA, back_of_head
from runtime_helpers import checkpoint


@pytest.fixture(scope="module")
def avatar():
    from facecapges.avatar.body import default_avatar

    return default_avatar(checkpoint().skeleton)


def _w(**kw) -> np.ndarray:
    a = np.zeros(len(ARKIT_NAMES), np.float32)
    for k, v in kw.items():
        a[ARKIT_NAMES.index(k)] = v
    return a


def test_back_of_head_faces_outwards():
    from facecapges.avatar.blendshapes import arkit_blendshapes

    face = arkit_blendshapes().neutral
    new, F, _, _ = back_of_head(face)
    V = np.concatenate([face.vertices, new])
    c = np.array([0.0, V[:, 1].min() + 0.5 * np.ptp(V[:, 1]), 0.0])
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert (np.einsum("ij,ij->i", n, V[F].mean(1) - c) > 0).all()  # inverted ones showed as a pale jaw seam


def test_eyeballs_turn_with_eyelook_targets(avatar):
    f = avatar.face
    pupil = np.unique(f.faces[PUPIL])
    left = pupil[f.vertices[pupil, 0] > 0]  # head frame: +X = the subject's left
    right = pupil[f.vertices[pupil, 0] < 0]
    d = f.deltas[f.names.index("eyeLookUpLeft")]
    assert d[left, 1].mean() > 0.2 and np.abs(d[right]).max() == 0  # the left pupil goes up (cm), the right stays
    d = f.deltas[f.names.index("eyeLookInLeft")]
    assert d[left, 0].mean() < -0.2  # in = towards the nose
    d = f.deltas[f.names.index("eyeLookOutRight")]
    assert d[right, 0].mean() < -0.2  # out = towards the ear
    sclera = np.unique(f.faces[SCLERA])
    assert np.abs(f.deltas[f.names.index("jawOpen")][sclera]).max() == 0


@pytest.mark.slow
def test_blinks_and_gaze_show_in_the_render():
    import cv2

    from facecapges.avatar.gltf import avatar_glb
    from facecapges.avatar.render.video import our_avatar, render_stills

    glb = avatar_glb(checkpoint().skeleton)
    ws = [_w(), _w(eyeBlinkLeft=1, eyeBlinkRight=1), _w(eyeLookOutLeft=1, eyeLookInRight=1),
          _w(eyeLookInLeft=1, eyeLookOutRight=1)]
    imgs = render_stills(our_avatar(glb), [None] * len(ws), ws, view="face", width=320, height=320)
    Path("/tmp/facecapges-eyes.png").write_bytes(cv2.imencode(".png", np.hstack(imgs))[1].tobytes())
    band = [im[int(0.34 * 320):int(0.42 * 320), int(0.25 * 320):int(0.75 * 320)].astype(int) for im in imgs]
    iris = [(b.max(-1) < 90) for b in band]  # iris and pupil: dark; skin, sclera and brows are lighter
    assert iris[0].sum() > 30
    assert iris[1].sum() < 0.25 * iris[0].sum()  # a blink covers them
    xs = [np.nonzero(m)[1].mean() for m in (iris[2], iris[3])]
    assert xs[0] - xs[1] > 2.0  # looking to the subject's left (image right) vs to their right
