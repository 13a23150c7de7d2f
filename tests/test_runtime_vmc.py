"""VMC over OSC/UDP: a python-osc server in the test receives what the sender sends."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.arkit import ARKIT_NAMES
from facecapges.io.bvh import read_bvh
from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.vmc import BEAT_TO_UNITY, VmcMapping, VmcSender
from facecapges.skeleton import UPPER_BODY

UNITY_BONES = {  # HumanBodyBones names the mapping may use
    "Hips", "Spine", "Chest", "UpperChest", "Neck", "Head",
    *[f"{s}{b}" for s in ("Left", "Right") for b in ("Shoulder", "UpperArm", "LowerArm", "Hand")],
    *[f"{s}{f}{seg}" for s in ("Left", "Right") for f in ("Thumb", "Index", "Middle", "Ring", "Little")
      for seg in ("Proximal", "Intermediate", "Distal")],
}


def axis_quat(axis: str, deg: float) -> np.ndarray:
    return rot.matrix_to_quaternion(rot.axis_angle_matrix(axis, np.array(np.radians(deg))))


def frame_with(rotations: dict[str, np.ndarray]) -> OutputFrame:
    q = np.tile([1.0, 0.0, 0.0, 0.0], (47, 1))
    for name, quat in rotations.items():
        q[UPPER_BODY.index(name)] = quat
    pose = rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)).astype(np.float32)
    face = np.zeros(52, np.float32)
    face[ARKIT_NAMES.index("jawOpen")] = 0.625
    return OutputFrame(7, 7 / 15, pose, q.astype(np.float32), face, rot.identity_rot6d(), True, {})


@pytest.fixture(scope="module")
def skeleton(beat_bvh):
    return read_bvh(beat_bvh).skeleton


def receive(sender_factory, frame):
    from pythonosc.dispatcher import Dispatcher
    from pythonosc.osc_server import ThreadingOSCUDPServer

    got = []
    disp = Dispatcher()
    disp.set_default_handler(lambda address, *args: got.append((address, args)))
    server = ThreadingOSCUDPServer(("127.0.0.1", 0), disp)
    th = threading.Thread(target=server.serve_forever, daemon=True)
    th.start()
    try:
        sender = sender_factory(*server.server_address)
        sender.write(frame)
        deadline = time.time() + 5
        while time.time() < deadline and not any(a == "/VMC/Ext/T" for a, _ in got):
            time.sleep(0.01)
        sender.close()
    finally:
        server.shutdown()
        server.server_close()
    return got


def test_vmc_messages(skeleton):
    fr = frame_with({"RightArm": axis_quat("Z", 30.0), "Neck1": axis_quat("X", 20.0),
                     "LeftHandIndex": axis_quat("Z", 10.0), "LeftHandIndex1": axis_quat("Z", 20.0)})
    got = receive(lambda h, p: VmcSender(skeleton, h, p), fr)
    addresses = [a for a, _ in got]
    assert addresses[0] == "/VMC/Ext/Root/Pos" and got[0][1][0] == "root"
    bones = {args[0]: np.array(args[1:], np.float64) for a, args in got if a == "/VMC/Ext/Bone/Pos"}
    assert set(bones) == set(BEAT_TO_UNITY.values()) and set(bones) <= UNITY_BONES
    assert len(bones) == 6 + 2 * (4 + 15)
    for name, v in bones.items():
        assert v.shape == (7,) and abs(np.linalg.norm(v[3:]) - 1) < 1e-5, name
    s15, c15 = np.sin(np.radians(15)), np.cos(np.radians(15))
    # right-handed +30° about Z → Unity (left-handed, X mirrored): −30° about Z, sent as (x, y, z, w)
    np.testing.assert_allclose(bones["RightUpperArm"][3:], [0, 0, -s15, c15], atol=1e-6)
    # Neck1 has no humanoid bone: its rotation is carried by Head (about X: unchanged by the X mirror)
    np.testing.assert_allclose(bones["Head"][3:], [np.sin(np.radians(10)), 0, 0, np.cos(np.radians(10))], atol=1e-6)
    np.testing.assert_allclose(bones["Neck"][3:], [0, 0, 0, 1], atol=1e-6)
    # the index metacarpal folds into IndexProximal: 10° + 20° about Z
    np.testing.assert_allclose(bones["LeftIndexProximal"][3:], [0, 0, -s15, c15], atol=1e-6)
    # positions: metres, x mirrored — the right arm is at +x in BEAT (cm), so at −x in Unity
    assert bones["RightUpperArm"][0] * skeleton.offsets[skeleton.index("RightArm")][0] < 0
    blends = [(args[0], args[1]) for a, args in got if a == "/VMC/Ext/Blend/Val"]
    assert [n for n, _ in blends] == list(ARKIT_NAMES)
    assert dict(blends)["jawOpen"] == pytest.approx(0.625)
    assert addresses.index("/VMC/Ext/Blend/Apply") > max(i for i, a in enumerate(addresses) if a == "/VMC/Ext/Blend/Val")
    assert ("/VMC/Ext/OK", (1,)) in got
    assert dict(got)["/VMC/Ext/T"][0] == pytest.approx(7 / 15)


def test_unity_quaternion_convention_matches_mirrored_points(skeleton):
    """The Unity quaternion rotates mirrored points the way the BVH rotation rotates the originals."""
    rng = np.random.default_rng(3)
    m = VmcMapping(skeleton)
    q47 = rot.matrix_to_quaternion(rot.rot6d_to_matrix(rng.normal(size=(47, 6))))
    bones = {name: q for name, _, q in m.local_rotations(q47)}
    M = np.diag([-1.0, 1.0, 1.0])
    for beat, unity in [("RightForeArm", "RightLowerArm"), ("LeftHand", "LeftHand"), ("Spine", "Spine")]:
        R = rot.quaternion_to_matrix(q47[UPPER_BODY.index(beat)])  # its parent maps 1:1, so local = local
        R_unity = rot.quaternion_to_matrix(bones[unity])
        p = rng.normal(size=3)
        np.testing.assert_allclose(R_unity @ (M @ p), M @ (R @ p), atol=1e-9)


def test_unreachable_receiver_does_not_raise(skeleton):
    sender = VmcSender(skeleton, "127.0.0.1", 9)  # discard port: nothing listens
    for _ in range(3):
        sender.write(frame_with({}))
    sender.close()
    assert sender.sent + sender.errors == 3
