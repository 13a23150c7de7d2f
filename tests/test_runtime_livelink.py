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
from facecapges.runtime.livelink import (LIVELINK_NAMES, LiveLinkReceiver, PacketError, decode_packet,
                                         encode_packet)

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
    # yaw > 0 turns the face (+Z of the head) towards the camera's +X (the image's right)
    R = rot.rot6d_to_matrix(fr.head_rot6d.astype(np.float64))
    forward = R @ np.array([0.0, 0.0, 1.0])
    assert forward[0] == pytest.approx(np.sin(0.3), abs=1e-6) and forward[2] == pytest.approx(np.cos(0.3), abs=1e-6)


def test_malformed_packets_raise_packet_error():
    good = build(sample_values())
    for n in range(len(good)):
        with pytest.raises(PacketError):
            decode_packet(good[:n])
    with pytest.raises(PacketError):
        decode_packet(good + b"\0")
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
                packets.append((False, base + bytes(rng.randrange(1, 20))))
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

    from runtime_helpers import cli_popen

    rec = tmp_path / "rec"
    proc = cli_popen("live", "--livelink", "0", "--audio", str(beat_wav), "--record", str(rec), "--max-seconds", "4")
    try:
        port = None
        deadline = time.time() + 120
        while time.time() < deadline and port is None:
            line = proc.stdout.readline()
            if not line:
                break
            if line.startswith("live: Live Link UDP 127.0.0.1:"):
                port = int(line.split("127.0.0.1:")[1].split()[0])
        assert port, proc.stderr.read()[-2000:]
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
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    rep = json.loads((rec / "report.json").read_text())
    assert rep["frames"] == 60 and rep["livelink"]["bad_packets"] >= 5 and rep["livelink"]["packets"] > 50
    face = read_face_json(rec / "face.json")
    jaw = face.weights[:, ARKIT_NAMES.index("jawOpen")]
    assert (np.abs(jaw - 0.8) < 1e-4).mean() > 0.5  # the phone's jaw drives the avatar's
