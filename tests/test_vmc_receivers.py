"""Our VMC stream applied to real VRM files by the receivers' rules (tests/vmc_receiver.py, written from EVMC4U's
receiver source, the VMC spec and UniVRM's loading rules — not from our sender).

Avatars: ours as VRM 1.0 (through ``avatar build --format vrm``) and as VRM 0.x, a long-armed VRM 0.x of other
proportions, a VRM 1.0 with random rest rotations and one with Blender-style rest rotations (tests/vrm_samples.py).
Checked after applying BEAT motion: the hips' height, every bone length, and each arm segment's direction against
BEAT's forward kinematics — with the receiver's bone-position sync on and off; and ``parts="arms"`` beside a face
tracker's stream.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from vmc_receiver import Receiver, osc_messages
from vrm_samples import build_sample

FRAMES = (120, 480, 840)  # of the BEAT take: arms in three different places
SEGMENTS = [(f"{S}{a}", f"{S}{b}", f"{S}{A}", f"{S}{B}") for S in ("Left", "Right")
            for a, b, A, B in (("UpperArm", "LowerArm", "Arm", "ForeArm"), ("LowerArm", "Hand", "ForeArm", "Hand"),
                               ("IndexProximal", "IndexIntermediate", "HandIndex1", "HandIndex2"))]
CHAIN = [("Hips", "Spine"), ("Spine", "Chest"), ("Chest", "UpperChest"), ("UpperChest", "Neck"), ("Neck", "Head")] + [
    (f"{S}{a}", f"{S}{b}") for S in ("Left", "Right") for a, b in (
        ("Shoulder", "UpperArm"), ("UpperArm", "LowerArm"), ("LowerArm", "Hand"), ("Hand", "IndexProximal"),
        ("IndexProximal", "IndexIntermediate"), ("Hand", "ThumbProximal"))]
ARMS = ("Shoulder", "UpperArm", "LowerArm", "Hand", "Thumb", "Index", "Middle", "Ring", "Little")


@pytest.fixture(scope="module")
def beat():
    from conftest import shared_file
    from facecapges import rotations as rot
    from facecapges.avatar.vrm.view import bvh_local_matrices
    from facecapges.io.bvh import read_bvh
    from facecapges.runtime.frames import OutputFrame
    from facecapges.skeleton import global_transforms, upper_body_indices

    m = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    L = bvh_local_matrices(m.skeleton, m.motion)[list(FRAMES)]
    G, P = global_transforms(m.skeleton, L)
    torso_still = L.copy()  # the torso at rest (arms only: the other tracker has it)
    torso_still[:, [m.skeleton.names.index(j) for j in ("Hips", "Spine", "Spine1", "Spine2", "Spine3")]] = np.eye(3)
    _, P_arms = global_transforms(m.skeleton, torso_still)
    q = rot.matrix_to_quaternion(L[:, upper_body_indices(m.skeleton)])
    frames = [OutputFrame(k, k / 15, rot.matrix_to_rot6d(L[i, upper_body_indices(m.skeleton)]), q[i],
                          np.zeros(52), rot.identity_rot6d(), True) for i, k in enumerate(FRAMES)]
    return {"skel": m.skeleton, "P": P, "G": G, "P_arms": P_arms, "frames": frames, "bvh": shared_file("data/beat/2_scott_0_1_1.bvh")}


@pytest.fixture(scope="module")
def avatars(beat, tmp_path_factory, our_vrms):
    """Ours (VRM 1.0 through the CLI, 0.x in-process: the session's ``our_vrms``) and the samples."""
    d = tmp_path_factory.mktemp("vmc_avatars")
    out = dict(our_vrms)
    for v in ("vrm0", "vrm1", "vrm1_blender"):
        out[v] = d / f"{v}.vrm"
        out[v].write_bytes(build_sample(v))
    return out


def stream(beat, frame, **kw) -> list:
    from facecapges.runtime.outputs.vmc import VmcSender

    s = VmcSender(beat["skel"], "127.0.0.1", 9, **kw)
    try:
        return osc_messages(s.datagrams_for(frame))
    finally:
        s.close()


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def measure(rx: Receiver, beat, i: int, fk: str = "P") -> dict:
    """Hips height change, the worst bone-length ratio and arm-direction errors after the stream of frame ``i``."""
    names = beat["skel"].names
    lengths = []
    for a, b in CHAIN:
        if a in rx.bones and b in rx.bones:
            rest = np.linalg.norm(rx.position(b, rest=True) - rx.position(a, rest=True))
            lengths.append(np.linalg.norm(rx.position(b) - rx.position(a)) / rest)
    errs = []
    for a, b, A, B in SEGMENTS:
        if a not in rx.bones or b not in rx.bones:
            errs.append(0.0 if "Index" in a else np.inf)  # (the VRM 0.x sample has no fingers)
        else:
            want = (beat[fk][i, names.index(B)] - beat[fk][i, names.index(A)]) * [-1, 1, 1]  # BEAT → Unity: x → −x
            errs.append(_angle(rx.position(b) - rx.position(a), want))
    # the bone (and the mesh skinned to it) turned by BEAT's global rotation from its own rest frame
    X = np.diag([-1.0, 1.0, 1.0])  # BEAT (right-handed) → Unity
    turn = []
    for bone, joint in (("LeftUpperArm", "LeftArm"), ("LeftLowerArm", "LeftForeArm"), ("RightHand", "RightHand")):
        got = rx.rotation(bone) @ rx.rest_world[1][rx.bones[bone]].T
        want = X @ beat["G"][i, names.index(joint)] @ X
        turn.append(float(np.degrees(np.arccos(np.clip((np.trace(got.T @ want) - 1) / 2, -1, 1)))))
    return {"hips": float(rx.position("Hips")[1]), "hips_rest": float(rx.position("Hips", rest=True)[1]),
            "turn_err": turn,
            "length_ratio": (float(min(lengths)), float(max(lengths))), "arm_err": errs}


@pytest.mark.parametrize("positions", [True, False], ids=["positions-on", "positions-off"])
@pytest.mark.parametrize("name, avatar_flag", [("ours", False), ("ours0", False), ("ours", True), ("vrm0", True),
                                               ("vrm1", True), ("vrm1_blender", True)])
def test_the_stream_keeps_the_avatar_whole(beat, avatars, name, avatar_flag, positions):
    """Our avatar without any flag, any avatar with --vmc-avatar: hips height and bone lengths kept, arms where BEAT says."""
    kw = {"avatar": avatars[name]} if avatar_flag else {}
    for i, fr in enumerate(beat["frames"]):
        rx = Receiver(avatars[name], bone_positions=positions)
        rx.apply(stream(beat, fr, **kw))
        m = measure(rx, beat, i)
        assert m["hips"] == pytest.approx(m["hips_rest"], abs=1e-4), m
        lo, hi = m["length_ratio"]
        assert lo > 0.999 and hi < 1.001, m
        arms, fingers = m["arm_err"][:2] + m["arm_err"][3:5], m["arm_err"][2:3] + m["arm_err"][5:]
        assert len(m["arm_err"]) == 6 and max(arms) < 2.0, m
        # a finger's rest direction differs a little between BEAT and the samples (the spec leaves it open)
        assert max(fingers) < 8.0, m
        assert max(m["turn_err"]) < 0.5, m  # the bone frames too, not only the joint positions
        if name.startswith("ours"):
            assert 0.85 < m["hips"] < 0.92 and max(m["arm_err"]) < 0.5, m  # BEAT's own skeleton: exact


def test_without_the_avatar_rest_rotations_and_proportions_go_wrong(beat, avatars):
    """Negative controls: our default rig on an avatar with rest rotations / other proportions."""
    rx = Receiver(avatars["vrm1_blender"], bone_positions=False)
    rx.apply(stream(beat, beat["frames"][0]))
    assert np.median(measure(rx, beat, 0)["arm_err"]) > 30  # the arm segments turn by their rest rotations
    rx = Receiver(avatars["vrm1_blender"], bone_positions=True)
    rx.apply(stream(beat, beat["frames"][0]))
    assert min(measure(rx, beat, 0)["turn_err"]) > 30  # positions on: the joints land, the bone frames do not
    rx = Receiver(avatars["vrm0"], bone_positions=True)
    rx.apply(stream(beat, beat["frames"][0]))
    lo, hi = measure(rx, beat, 0)["length_ratio"]
    assert lo < 0.9 or hi > 1.1  # our positions on an avatar of other proportions reshape it


def test_arms_only_leaves_head_face_and_torso_to_the_face_tracker(beat, avatars):
    """``parts="arms"`` beside another tracker's stream: head, spine, root and face stay the tracker's."""
    msgs = stream(beat, beat["frames"][1], parts="arms", blend="both")
    addresses = {a for a, _ in msgs}
    bones = {args[0] for a, args in msgs if a == "/VMC/Ext/Bone/Pos"}
    assert addresses == {"/VMC/Ext/Bone/Pos", "/VMC/Ext/OK", "/VMC/Ext/T"}, addresses
    assert bones and all(any(w in b for w in ARMS) for b in bones) and len(bones) == 2 * (4 + 15)
    # the face tracker (e.g. VSeeFace's webcam tracking through a second VMC source): head turned, a blink
    yaw = [0.0, np.sin(np.radians(10)), 0.0, np.cos(np.radians(10))]
    tracker = [("/VMC/Ext/Root/Pos", ("root", 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)),
               ("/VMC/Ext/Bone/Pos", ("Head", *Receiver(avatars["ours"]).t[Receiver(avatars["ours"]).bones["Head"]],
                                      *yaw)),
               ("/VMC/Ext/Blend/Val", ("Blink", 1.0)), ("/VMC/Ext/Blend/Apply", ())]
    rx = Receiver(avatars["ours"])
    rx.apply(tracker)
    head_before = rx.rotation("Head").copy()
    rx.apply(msgs)
    np.testing.assert_allclose(rx.rotation("Head"), head_before, atol=1e-9)
    assert rx.applied_blend == {"blink": 1.0} and rx.model_t[0] == pytest.approx(0.3)
    m = measure(rx, beat, 1, "P_arms")  # the arms relative to the torso the tracker holds still
    assert max(m["arm_err"]) < 0.5 and m["length_ratio"][0] > 0.999, m


def test_upper_sends_no_root_and_no_hips(beat):
    msgs = stream(beat, beat["frames"][0], parts="upper")
    bones = {args[0] for a, args in msgs if a == "/VMC/Ext/Bone/Pos"}
    assert "Hips" not in bones and {"Spine", "Head", "LeftHand"} <= bones
    assert "/VMC/Ext/Root/Pos" not in {a for a, _ in msgs} and "/VMC/Ext/Blend/Apply" in {a for a, _ in msgs}
