"""The engine contract (``facecapges.engine.contract``), checked over every engine the package ships:
one stream and the batched streams ``serve`` runs, with the slot lifecycle (open, reset, close) and the
intensity dial. A new engine is added to ``STYLES`` and meets the same checks."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from conftest import shared_file
from facecapges import timing
from facecapges.engine.contract import BatchedStreams, GestureEngine, Stream
from facecapges.styles import DEFAULT_NETWORK_STYLE, DEFAULT_STYLE, load_style
from tolerances import assert_rotations_close

STYLES = {"matching": DEFAULT_STYLE, "network": DEFAULT_NETWORK_STYLE}
SPF = timing.samples_per_frame()


def _inputs(n: int, seed: int):
    """``n`` frames of his unseen speech (2_scott_0_4_4, from second ``seed``), no face, head at rest."""
    audio = _speech()[seed * 16000:][: n * SPF]
    face = np.zeros((n, 52), np.float32)
    head = np.tile(np.array([1, 0, 0, 0, 1, 0], np.float32), (n, 1))
    return audio.reshape(n, SPF), face, head


@functools.lru_cache(maxsize=1)
def _speech() -> np.ndarray:
    from facecapges.io.audio import load_audio

    return load_audio(shared_file("data/beat/2_scott_0_4_4.wav"))


@pytest.fixture(scope="module", params=sorted(STYLES))
def style(request) -> GestureEngine:
    st = load_style(style=STYLES[request.param])
    assert st.engine == request.param
    return st


class TestContract:
    def test_interfaces(self, style):
        assert isinstance(style, GestureEngine)
        assert isinstance(style.streaming(), Stream)
        assert isinstance(style.batched(2), BatchedStreams)
        assert style.neutral_window.shape[1:] == (47, 6) and style.fps == timing.MODEL_FPS

    def test_one_stream_and_a_batch_slot_agree(self, style):
        n = 40
        audio, face, head = _inputs(n, 0)
        one = style.streaming()
        single = np.stack([one.step(audio[k], face[k], head[k]) for k in range(n)])
        assert one.frames == n and single.shape == (n, 47, 6) and np.isfinite(single).all()
        batch = style.batched(2)
        other, mine = batch.open(), batch.open()  # the stream under test in the second slot
        a2, f2, h2 = _inputs(n, 1)
        got = np.stack([
            batch.step([other, mine], np.stack([a2[k], audio[k]]), np.stack([f2[k], face[k]]), np.stack([h2[k], head[k]]))[1]
            for k in range(n)
        ])
        assert_rotations_close(got, single)

    def test_slot_lifecycle(self, style):
        batch = style.batched(1)
        a = batch.open()
        b = batch.open()  # grows past its capacity
        assert batch.n_open == 2 and batch.open_slots == {a, b}
        batch.close(a)
        assert batch.open_slots == {b}
        with pytest.raises((KeyError, ValueError)):
            batch.step([a], *(x[:1] for x in _inputs(1, 0)))
        c = batch.open()
        assert c == a  # the lowest free slot is reused
        audio, face, head = _inputs(20, 2)
        first = [batch.step([c], audio[k:k + 1], face[k:k + 1], head[k:k + 1])[0] for k in range(20)]
        batch.reset(c)
        again = [batch.step([c], audio[k:k + 1], face[k:k + 1], head[k:k + 1])[0] for k in range(20)]
        np.testing.assert_array_equal(np.stack(again), np.stack(first))  # same code path: same bits

    def test_the_dial_at_zero_stills_the_motion(self, style):
        """Intensity 0 is rest (the network: its rest pose; matching: idle rows at half their motion): the joints
        turn less than at 1 on the same speech (here: network ~0, matching 0.68× over all 47 joints)."""
        from facecapges import rotations as rot

        audio, face, head = _inputs(90, 20)
        speed = {}
        for dial in (1.0, 0.0):
            batch = style.batched(1)
            s = batch.open()
            batch.set_intensity(s, dial)
            poses = np.stack([batch.step([s], audio[k:k + 1], face[k:k + 1], head[k:k + 1])[0] for k in range(90)])
            m = rot.rot6d_to_matrix(poses)
            speed[dial] = float(np.mean(rot.geodesic_angle(m[31:], m[30:-1])))  # after the dial has eased
        assert speed[0.0] < 0.85 * speed[1.0], speed
