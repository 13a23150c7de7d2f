"""The gesture intensity dial (facecapges.engine.intensity) through the generators, the protocol and serve."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from facecapges import rotations as rot
from facecapges.engine.intensity import MAX_INTENSITY, check_intensity, rest_pose, scale_pose
from facecapges.errors import UserError
from facecapges.network.config import ModelConfig
from facecapges.network.network import FaceCapGes
from facecapges.network.style import NetworkStyle
from facecapges.runtime.outputs import protocol
from tolerances import assert_rotations_close


@pytest.fixture(scope="module")
def ckpt() -> NetworkStyle:
    torch.manual_seed(0)
    model = FaceCapGes(ModelConfig()).eval()
    with torch.no_grad():
        for p in model.decoder.parameters():
            p.mul_(2.0)  # a random model that moves
    neutral = (np.random.default_rng(1).normal(size=(16, 47, 6)) * 0.3).astype(np.float32)
    meta = {"neutral_window": neutral.tolist(), "model_config": {"fps": 15}}
    return NetworkStyle(model=model, meta=meta, path=Path("random-init"))


def _frames(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    head = rot.identity_rot6d().astype(np.float32)
    return [((rng.normal(size=1067) * 0.2).astype(np.float32), rng.uniform(size=52).astype(np.float32), head)
            for _ in range(n)]


def test_scale_pose_is_a_slerp_about_rest():
    rng = np.random.default_rng(0)
    rest = rot.normalize_rot6d(rng.normal(size=(47, 6)))
    pose = rot.normalize_rot6d(rest + 0.2 * rng.normal(size=(47, 6)))
    R0, R1 = rot.rot6d_to_matrix(rest), rot.rot6d_to_matrix(pose)
    base = rot.geodesic_angle(R0, R1)
    assert np.allclose(scale_pose(pose, rest, 0.0), rest, atol=1e-5)
    assert np.allclose(scale_pose(pose, rest, 1.0), pose, atol=1e-5)
    for g in (0.5, MAX_INTENSITY):
        got = rot.geodesic_angle(R0, rot.rot6d_to_matrix(scale_pose(pose, rest, g).astype(np.float64)))
        assert np.allclose(got, g * base, atol=1e-4)
    # one gain per pose
    two = scale_pose(np.stack([pose, pose]), rest, np.array([0.0, 1.0]))
    assert np.allclose(two[0], rest, atol=1e-5) and np.allclose(two[1], pose, atol=1e-5)


@pytest.mark.parametrize("bad", [-0.1, 1.31, float("nan"), "loud", None])
def test_check_intensity_refuses(bad):
    with pytest.raises(UserError, match="intensity"):
        check_intensity(bad)


def test_network_generator_scales_what_it_shows_not_what_it_feeds_back(ckpt):
    fr = _frames(40)
    plain = ckpt.streaming()
    ref = np.array([plain.step(*x) for x in fr])
    g = ckpt.streaming()
    out = []
    for t, x in enumerate(fr):
        g.intensity = 0.0 if 10 <= t < 20 else 1.0
        out.append(g.step(*x))
    out = np.array(out)
    rest = rest_pose(ckpt.neutral_window)
    assert np.allclose(out[10:20], rest, atol=1e-5)  # rest while the dial is at 0 …
    assert np.allclose(out[20:], ref[20:], atol=1e-5)  # … and the same motion after: the history was unscaled
    g.reset()
    g.intensity = 1.3
    big = np.array([g.step(*x) for x in fr])
    ang = lambda p: rot.geodesic_angle(rot.rot6d_to_matrix(rest.astype(np.float64)), rot.rot6d_to_matrix(p.astype(np.float64)))  # noqa: E731
    small = 1.3 * ang(ref) < np.pi - 0.1  # past π the arc wraps round (a random model turns joints far)
    assert small.mean() > 0.3
    assert np.allclose(ang(big)[small], 1.3 * ang(ref)[small], atol=1e-3)


def test_batched_slots_have_their_own_dial(ckpt):
    fr = _frames(12, seed=3)
    gen = ckpt.batched(capacity=2)
    a, b = gen.open(), gen.open()
    gen.set_intensity(b, 0.0)
    with pytest.raises(UserError):
        gen.set_intensity(a, 2.0)
    rest = rest_pose(ckpt.neutral_window)
    single = ckpt.streaming()
    for x in fr:
        p = gen.step([a, b], [x[0], x[0]], np.stack([x[1], x[1]]), np.stack([x[2], x[2]]))
        # a batch of 2 against one stream: float32 rounding, 0.01° (tolerances.py)
        assert_rotations_close(p[0], single.step(*x), what="the slot at intensity 1")
        assert_rotations_close(p[1], rest, what="the slot at intensity 0")


def test_protocol_intensity_message():
    assert protocol.decode_client(json.dumps({"type": "intensity", "value": 0.5})) == {"type": "intensity", "value": 0.5}
    for bad in (2.0, -1, "x", True, None):
        with pytest.raises(protocol.ProtocolError, match="value"):
            protocol.decode_client(json.dumps({"type": "intensity", "value": bad}))
    assert json.loads(protocol.encode_hello(intensity=0.7))["intensity"] == 0.7


def test_serve_client_sets_its_own_intensity(ckpt):
    from websockets.asyncio.client import connect

    from facecapges.serving.server import ServeConfig, StreamServer

    server = StreamServer(ckpt, ServeConfig(port=0, intensity=1.0)).start()
    rest = rest_pose(ckpt.neutral_window)
    fr = _frames(6, seed=5)

    async def client(value):
        async with connect(server.url) as ws:
            hello = json.loads(await ws.recv())
            assert hello["intensity"] == 1.0
            await ws.send(json.dumps({"type": "intensity", "value": value}))
            assert json.loads(await ws.recv()) == {"type": "intensity", "value": value}
            quats = []
            for k, (a, f, h) in enumerate(fr):
                await ws.send(protocol.encode_input(k, a, f, h))
                quats.append(json.loads(await ws.recv())["pose"])
            return np.array(quats).reshape(len(fr), 47, 4)

    try:
        q0 = asyncio.run(client(0.0))
    finally:
        server.close()
    want = rot.rot6d_to_quaternion(rest.astype(np.float64))
    same = np.abs((q0 * want[None]).sum(-1))  # |cos| of the half-angle between the rotations
    assert same.min() > 1 - 1e-6
