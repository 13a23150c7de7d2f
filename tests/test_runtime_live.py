"""``live`` says what it does: a viewer when no output is chosen, and why a phone's packets do not arrive."""

from __future__ import annotations

import gzip
import socket
import struct
import time

from facecapges.runtime.live import livelink_hint
from facecapges.runtime.inputs.sources import LiveLinkFace

from runtime_helpers import cli

HINT = "no packets yet — is the phone set to this machine's LAN address? use --host 0.0.0.0"


def test_live_without_outputs_opens_the_viewer(face_video):
    r = cli("live", "--video", str(face_video), "--max-seconds", "1")
    assert r.returncode == 0, r.stderr
    assert "opening the browser viewer" in r.stdout and "--vmc" in r.stdout and "--record" in r.stdout
    assert any(line.startswith("viewer: http://127.0.0.1:") for line in r.stdout.splitlines()), r.stdout


def test_livelink_on_loopback_says_a_phone_cannot_reach_it(beat_wav, tmp_path):
    r = cli("live", "--livelink", "0", "--audio", str(beat_wav), "--record", str(tmp_path), "--max-seconds", "6")
    assert r.returncode == 0, r.stderr
    assert "which a phone cannot reach: add --host 0.0.0.0" in r.stderr, r.stderr
    assert HINT in r.stderr  # the status line while nothing arrives


def _packets(path):
    raw = gzip.decompress(path.read_bytes())
    n = struct.unpack(">I", raw[1:5])[0]
    i, out = 5, []
    for _ in range(n):
        (m,) = struct.unpack(">I", raw[i:i + 4])
        out.append(raw[i + 4:i + 4 + m])
        i += 4 + m
    return out


def test_hint_goes_away_with_the_first_real_packet():
    from conftest import shared_file

    feed = LiveLinkFace(0, "127.0.0.1")
    try:
        assert livelink_hint(feed, "127.0.0.1", waiting=True) == HINT
        assert "cannot reach" in livelink_hint(feed, "127.0.0.1")
        pkt = _packets(shared_file("data/livelink/dao.gesichter"))[0]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(pkt, feed.receiver.address)
        deadline = time.time() + 5
        while time.time() < deadline and feed.receiver.stats()["packets"] == 0:
            time.sleep(0.02)
        assert livelink_hint(feed, "127.0.0.1", waiting=True) is None
    finally:
        feed.close()
    assert livelink_hint.__doc__
