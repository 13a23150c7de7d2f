"""Live Link Face packets built here with struct: decoding, mapping, and a receiver that never crashes."""

from __future__ import annotations

import random
import socket
import struct
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facecapges import rotations as rot
from facecapges.arkit import ARKIT_NAMES
from facecapges.runtime.inputs.livelink import (
    LIVELINK_NAMES,
    LiveLinkReceiver,
    PacketError,
    decode_packet,
    encode_packet,
)

DEVICE = "1F2E3D4C-5B6A-7980-A1B2-C3D4E5F60718"


def build(values, subject="iPhone", device=DEVICE, frame=1234, sub=0.25, rate=(60, 1), version=6, count=61):
    """A packet laid out as the module docstring says, independently of encode_packet."""
    d, s = device.encode(), subject.encode()
    return (struct.pack(">B", version) + struct.pack(">i", len(d)) + d + struct.pack(">i", len(s)) + s
            + struct.pack(">i", frame) + struct.pack(">f", sub) + struct.pack(">ii", *rate)
            + struct.pack(">B", count) + struct.pack(f">{len(values)}f", *values))


def sample_values(seed=0):
    rng = np.random.default_rng(seed)
    v = np.concatenate([rng.uniform(0, 1, 52), rng.uniform(-0.5, 0.5, 9)]).astype(np.float32)
    return v


def test_decode_fields_and_size():
    v = sample_values()
    pkt = build(v, subject="MyiPhone13Pro")
    assert len(pkt) == 1 + 4 + 36 + 4 + 13 + 16 + 1 + 61 * 4 == 319
    fr = decode_packet(pkt)
    assert fr.device_id == DEVICE and fr.subject == "MyiPhone13Pro"
    assert fr.frame_number == 1234 and fr.sub_frame == pytest.approx(0.25) and fr.rate == (60, 1)
    assert fr.time_s == pytest.approx(1234.25 / 60)
    np.testing.assert_array_equal(fr.values, v)
    assert encode_packet(v, DEVICE, "MyiPhone13Pro", 1234, 0.25, (60, 1)) == pkt


def test_blendshapes_reordered_by_name_and_head_rotation():
    v = np.zeros(61, np.float32)
    v[LIVELINK_NAMES.index("EyeBlinkLeft")] = 0.7
    v[LIVELINK_NAMES.index("JawOpen")] = 0.4
    v[LIVELINK_NAMES.index("TongueOut")] = 1.0
    v[LIVELINK_NAMES.index("MouthSmileRight")] = 0.3
    v[LIVELINK_NAMES.index("HeadYaw")] = 0.3
    fr = decode_packet(build(v))
    w = fr.weights52
    assert w[ARKIT_NAMES.index("eyeBlinkLeft")] == pytest.approx(0.7)
    assert w[ARKIT_NAMES.index("jawOpen")] == pytest.approx(0.4)
    assert w[ARKIT_NAMES.index("tongueOut")] == pytest.approx(1.0)
    assert w[ARKIT_NAMES.index("mouthSmileRight")] == pytest.approx(0.3)
    assert np.count_nonzero(w) == 4
    # the wire's HeadYaw > 0 turns the head to the subject's right: the face (+Z of the head) towards the
    # camera's −X (the image's left); our yaw (> 0 to the subject's left) is its negative
    R = rot.rot6d_to_matrix(fr.head_rot6d.astype(np.float64))
    forward = R @ np.array([0.0, 0.0, 1.0])
    assert forward[0] == pytest.approx(-np.sin(0.3), abs=1e-6) and forward[2] == pytest.approx(np.cos(0.3), abs=1e-6)
    np.testing.assert_allclose(fr.head_angles, [-0.3, 0.0, 0.0], atol=1e-7)


def test_malformed_packets_raise_packet_error():
    good = build(sample_values())
    for n in range(len(good)):
        with pytest.raises(PacketError):
            decode_packet(good[:n])
    with pytest.raises(PacketError):
        decode_packet(build(sample_values(), version=5))
    with pytest.raises(PacketError):
        decode_packet(build(sample_values()[:60], count=60))
    bad = bytearray(good)
    bad[1:5] = struct.pack(">i", 2_000_000_000)
    with pytest.raises(PacketError):
        decode_packet(bytes(bad))
    with pytest.raises(PacketError):
        decode_packet(build(np.r_[sample_values()[:60], np.nan]))


def test_trailing_bytes_are_ignored():
    """Unreal's receiver reads the fields it knows and ignores the rest; so do we."""
    v = sample_values(4)
    for extra in (b"\0", b"\xaa\xbb\xcc", bytes(64)):
        fr = decode_packet(build(v) + extra)
        np.testing.assert_array_equal(fr.values, v)
        assert fr.frame_number == 1234


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=400))
def test_any_bytes_decode_or_packet_error(data):
    try:
        fr = decode_packet(data)
    except PacketError:
        return
    assert fr.values.shape == (61,)


def _wait(rx, total, timeout=10.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        s = rx.stats()
        if s["packets"] + s["bad_packets"] >= total:
            return s
        time.sleep(0.01)
    return rx.stats()


def test_receiver_survives_thousands_of_bad_packets():
    rx = LiveLinkReceiver(port=0)
    try:
        assert rx.address[0] == "127.0.0.1"  # loopback unless the user asks otherwise
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rng = random.Random(7)
        good_sent = bad_sent = 0
        last_good = None
        packets = []
        base = build(sample_values(1))
        for i in range(3000):
            kind = i % 6
            if kind == 0:
                v = sample_values(i)
                packets.append((True, build(v, frame=i)))
                last_good = v
            elif kind == 1:
                packets.append((False, bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 400)))))
            elif kind == 2:
                packets.append((False, base[:rng.randrange(0, len(base))]))
            elif kind == 3:
                b = bytearray(base)
                b[rng.choice([0, 1, 2, 3, 41, 42, 43, 67])] ^= 0xFF  # version, a length or the count corrupted
                packets.append((False, bytes(b)))
            elif kind == 4:
                packets.append((False, base[:-rng.randrange(1, 20)]))
            else:
                packets.append((False, b""))
        sent = 0
        for k in range(0, len(packets), 50):  # in batches: never overflow the socket buffer
            for ok, p in packets[k:k + 50]:
                tx.sendto(p, rx.address)
                good_sent += ok
                bad_sent += not ok
            sent += len(packets[k:k + 50])
            _wait(rx, sent)
        s = _wait(rx, sent)
        assert s["packets"] == good_sent == 500
        assert s["bad_packets"] == bad_sent == 2500
        assert rx._thread.is_alive()
        seq, fr = rx.latest()
        assert seq == good_sent
        np.testing.assert_array_equal(fr.values, last_good)
        tx.sendto(build(sample_values(99), frame=99999), rx.address)  # still decoding after all that
        _wait(rx, sent + 1)
        assert rx.latest()[1].frame_number == 99999
        tx.close()
    finally:
        rx.close()


def test_live_command_with_livelink(beat_wav, tmp_path):
    """``live --livelink``: packets from the test drive the face; bad ones are counted in the report."""
    import json

    from facecapges.io.face_json import read_face_json
    from runtime_helpers import cli_popen, wait_line

    rec = tmp_path / "rec"
    proc = cli_popen("live", "--livelink", "0", "--audio", str(beat_wav), "--record", str(rec), "--max-seconds", "4")
    try:
        line = wait_line(proc, "live: Live Link UDP 127.0.0.1:")
        assert line, proc.stderr.read()[-2000:]
        port = int(line.split("127.0.0.1:")[1].split()[0])
        v = np.zeros(61, np.float32)
        v[LIVELINK_NAMES.index("JawOpen")] = 0.8
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        k = 0
        while proc.poll() is None and k < 400:
            tx.sendto(build(v, frame=k), ("127.0.0.1", port))
            if k % 10 == 0:
                tx.sendto(b"garbage", ("127.0.0.1", port))
            k += 1
            time.sleep(1 / 60)
        tx.close()
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    rep = json.loads((rec / "report.json").read_text())
    assert rep["frames"] == 60 and rep["livelink"]["bad_packets"] >= 5 and rep["livelink"]["packets"] > 50
    face = read_face_json(rec / "face.json")
    jaw = face.weights[:, ARKIT_NAMES.index("jawOpen")]
    assert (np.abs(jaw - 0.8) < 1e-4).mean() > 0.5  # the phone's jaw drives the avatar's


# ---------------------------------------------------------------- real recordings (LLV project, BSD-2)
def recording(name: str) -> list:
    """Decode a ``.gesichter`` file: gzip; one byte; big-endian uint32 count; per frame uint32 length + packet."""
    import gzip

    from conftest import shared_file

    raw = gzip.decompress(shared_file(f"data/livelink/{name}").read_bytes())
    (count,) = struct.unpack_from(">I", raw, 1)
    pos, frames = 5, []
    for _ in range(count):
        (n,) = struct.unpack_from(">I", raw, pos)
        frames.append(decode_packet(raw[pos + 4:pos + 4 + n]))
        pos += 4 + n
    assert pos == len(raw)
    return frames


def test_recordings_decode_every_packet():
    counts = {n: len(recording(n)) for n in ("dao.gesichter", "debug-headyaw.gesichter",
                                              "debug-lefteyepitch.gesichter", "debug-all-blendshapes.gesichter")}
    assert counts == {"dao.gesichter": 180, "debug-headyaw.gesichter": 66, "debug-lefteyepitch.gesichter": 66,
                      "debug-all-blendshapes.gesichter": 3660}


def test_real_face_angles_are_radians():
    """The eye angle per unit of EyeLook* weight is the eye's range: 35° as radians, 110° as degrees/180."""
    frames = recording("dao.gesichter")
    V = np.array([f.values for f in frames], np.float64)
    col = {n: V[:, i] for i, n in enumerate(LIVELINK_NAMES)}
    horizontal = col["EyeLookInLeft"] - col["EyeLookOutLeft"]
    slope = np.polyfit(horizontal, col["LeftEyeYaw"], 1)[0]
    assert np.corrcoef(horizontal, col["LeftEyeYaw"])[0, 1] > 0.999
    assert 0.45 < slope < 0.8  # a full look = 26°–46° if radians (as degrees/180 it would be 81°–144°)
    vertical = col["EyeLookDownLeft"] - col["EyeLookUpLeft"]
    assert 0.45 < np.polyfit(vertical, col["LeftEyePitch"], 1)[0] < 0.8
    head = np.degrees(np.array([f.head_angles for f in frames]))
    assert np.abs(head).max() < 30.0 and np.ptp(head[:, 0]) > 15.0  # a moving head, within a neck's range


def test_real_face_head_follows_the_eyes():
    """Eyes lead the head in a gaze shift: eye yaw (> 0 = rightward gaze, Apple's EyeLookIn/Out) leads head yaw."""
    frames = recording("dao.gesichter")
    V = np.array([f.values for f in frames], np.float64)
    eye_yaw = V[:, LIVELINK_NAMES.index("LeftEyeYaw")] + V[:, LIVELINK_NAMES.index("RightEyeYaw")]
    wire_yaw = V[:, LIVELINK_NAMES.index("HeadYaw")]
    lags = range(0, 6)
    corr = [np.corrcoef(eye_yaw[:len(eye_yaw) - k], wire_yaw[k:])[0, 1] for k in lags]
    assert max(corr) > 0.95 and int(np.argmax(corr)) >= 1  # same direction, eyes first
    # so a gaze to the subject's right turns our head to the subject's right: our yaw < 0 there
    ours = np.array([f.head_angles[0] for f in frames])
    assert np.corrcoef(eye_yaw, ours)[0, 1] < -0.9


def test_debug_head_yaw_sweep_turns_about_the_vertical_axis():
    frames = recording("debug-headyaw.gesichter")
    wire = np.array([f.values[LIVELINK_NAMES.index("HeadYaw")] for f in frames])
    assert wire.min() == pytest.approx(-1.0) and wire.max() == pytest.approx(1.0)
    for f, w in zip(frames, wire):
        R = rot.rot6d_to_matrix(f.head_rot6d.astype(np.float64))
        np.testing.assert_allclose(R @ np.array([0.0, 1.0, 0.0]), [0, 1, 0], atol=1e-6)  # up stays up
        forward = R @ np.array([0.0, 0.0, 1.0])
        assert np.arctan2(forward[0], forward[2]) == pytest.approx(-w, abs=1e-5)  # radians, yaw negated
    eye = recording("debug-lefteyepitch.gesichter")
    for f in eye:  # an eye sweep leaves the head alone
        np.testing.assert_allclose(rot.rot6d_to_matrix(f.head_rot6d.astype(np.float64)), np.eye(3), atol=1e-7)
