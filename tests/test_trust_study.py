"""Attacks on the study server, each bounded and on loopback only: forged answers, unbounded or
malformed bodies, idle and excess connections, damaged answer files, deep JSON, long paths."""

from __future__ import annotations

import json
import socket
import time
import urllib.error
import urllib.request

import pytest

from _study_media import make_clips
from facecapges.study.analyze import collect_answers
from facecapges.study.build import INVITATIONS_FILE, create_study, ensure_tokens, open_study
from facecapges.study.server import MAX_BODY, make_server, serve_in_thread
from facecapges.study.store import MAX_PLAYS
from runtime_helpers import cli

GOOD = {"realism": [1, 2, 3], "synchrony": [3, 1, 2], "diversity": [2, 3, 1]}


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory, beat_bvh, beat_wav):
    tmp = tmp_path_factory.mktemp("trust_study")
    y = make_clips(tmp / "src", beat_bvh, beat_wav, n_clips=2, seconds=2.0)
    create_study(y, tmp / "study", 3, seed=5, progress=False)
    return tmp / "study"


class Served:
    def __init__(self, study_dir, **kw):
        self.log: list[str] = []
        self.study = open_study(study_dir)
        self.server = make_server(self.study, "127.0.0.1", 0, on_event=self.log.append, **kw)
        serve_in_thread(self.server)
        self.port = self.server.server_address[1]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()

    def token(self, pid):
        return self.study.plan.participant(pid).token

    def json(self, path, body=None):
        data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
        r = urllib.request.Request(f"http://127.0.0.1:{self.port}{path}", data=data,
                                   headers={"Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(r, timeout=20) as resp:
                return resp.status, json.loads(resp.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read() or b"{}")

    def raw(self, data: bytes, read_timeout: float = 10.0) -> bytes:
        """Send raw bytes, return what the server answers until it closes (or the timeout)."""
        with socket.create_connection(("127.0.0.1", self.port), timeout=read_timeout) as s:
            s.sendall(data)
            got = b""
            try:
                while chunk := s.recv(65536):
                    got += chunk
            except (TimeoutError, ConnectionResetError):
                pass
            return got


def test_invitations_are_the_only_credential_and_forged_answers_are_not_analysed(study_dir):
    lines = (study_dir / INVITATIONS_FILE).read_text().splitlines()
    assert len(lines) == 4 and lines[1].startswith("P01\thttp://") and "/?invite=" in lines[1]
    with Served(study_dir) as s:
        tokens = [p.token for p in s.study.plan.participants]
        assert len(set(tokens)) == 3 and all(len(t) >= 22 for t in tokens)
        # the attack of the issue: answer for P02 knowing only the id
        for body in ({"participant": "P02", "index": 0, "ranks": GOOD},
                     {"participant": "P02", "token": "", "index": 0, "ranks": GOOD},
                     {"token": "P02", "index": 0, "ranks": GOOD},
                     {"token": tokens[1][:-1] + "x", "index": 0, "ranks": GOOD}):
            status, err = s.json("/api/answer", body)
            assert status == 401 and "invitation" in err["error"]
        assert s.json("/api/trial?participant=P02&index=0")[0] == 401
        assert not (study_dir / "responses" / "P02.json").exists()  # nothing recorded, nobody locked out
        # the real P02 answers with the token from the link
        status, st = s.json("/api/answer", {"token": s.token("P02"), "index": 0, "ranks": GOOD})
        assert status == 200 and st["next"] == 1
    # a responses file written past the server (no token digest) is left out of the analysis
    forged = {"participant": "P03", "history": [{"type": "answer", "trial": 0, "clip": "x", "positions": [],
                                                "ranks": {}}]}
    (study_dir / "responses" / "P03.json").write_text(json.dumps(forged))
    left: list[str] = []
    answers = collect_answers(open_study(study_dir), left)
    assert [a["participant"] for a in answers] == ["P02"] and left == ["P03 clip 1"]
    (study_dir / "responses" / "P03.json").unlink()


def test_a_study_without_tokens_gets_them_and_its_old_answers_are_left_out(tmp_path, study_dir):
    import shutil

    d = tmp_path / "old"
    shutil.copytree(study_dir, d)
    # its own old answer, not the one an earlier test of this file left in study_dir: under xdist that test
    # may have run on the other worker (each worker builds its own study_dir)
    for f in (d / "responses").glob("*.json"):
        f.unlink()
    with Served(d) as s:  # P02 answers while the study has its tokens: the answer from before, below
        assert s.json("/api/answer", {"token": s.token("P02"), "index": 0, "ranks": GOOD})[0] == 200
    doc = json.loads((d / "study.json").read_text())
    for p in doc["plan"]["participants"]:
        p.pop("token")
    (d / "study.json").write_text(json.dumps(doc))
    st = open_study(d)
    assert ensure_tokens(st) == 3 and ensure_tokens(open_study(d)) == 0
    assert all(p.token for p in open_study(d).plan.participants)
    left: list[str] = []
    assert collect_answers(open_study(d), left) == [] and left  # P02's answer above predates these tokens


@pytest.mark.parametrize("header, status, reason", [
    (b"Content-Length: -1\r\n", 400, b"must be a number"),
    (b"Content-Length: abc\r\n", 400, b"must be a number"),
    (b"", 411, b"Content-Length is required"),
    (b"Content-Length: 300000000\r\n", 413, b"request too large"),
])
@pytest.mark.serial
def test_request_bodies_are_bounded(study_dir, header, status, reason):
    with Served(study_dir) as s:
        t0 = time.monotonic()
        # the stream behind the header would be 300 MB: the server must answer without reading it
        got = s.raw(b"POST /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\n" + header + b"\r\n" + b"[" * 4096)
        assert got.startswith(f"HTTP/1.0 {status}".encode()) or got.startswith(f"HTTP/1.1 {status}".encode()), got
        assert reason in got and time.monotonic() - t0 < 5
        assert s.json("/api/info")[0] == 200  # still serving


def test_deep_json_and_long_paths_are_bad_input_not_tracebacks(study_dir, capfd):
    with Served(study_dir) as s:
        deep = b"[" * 60000  # fits in MAX_BODY, deeper than the parser can go
        assert len(deep) < MAX_BODY
        status, err = s.json("/api/session", deep)
        assert status == 400 and err["error"] == "request body is not JSON"
        status, err = s.json("/api/answer", json.dumps({"token": s.token("P01"), "index": 0,
                                                        "ranks": {"realism": [[[[1]]]]}}).encode())
        assert status == 409
        for path in ("/three/" + "a" * 5000, "/page/" + "b/" * 3000, "/" + "c" * 5000):
            assert s.json(path)[0] == 404
    assert "Traceback" not in capfd.readouterr().err


@pytest.mark.serial
def test_idle_and_excess_connections_are_dropped(study_dir):
    with Served(study_dir, timeout=1.0, max_connections=4) as s:
        t0 = time.monotonic()
        # a client that never finishes its request is closed after the socket timeout
        got = s.raw(b"POST /api/session HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n{", read_timeout=10)
        assert time.monotonic() - t0 < 5 and b"200" not in got
        idle = [socket.create_connection(("127.0.0.1", s.port), timeout=5) for _ in range(4)]
        try:
            time.sleep(0.2)
            got = s.raw(b"GET /api/info HTTP/1.1\r\nHost: x\r\n\r\n")
            # every slot taken by a connection waiting for its request: the oldest makes room
            assert got.startswith(b"HTTP/1.1 200") or got.startswith(b"HTTP/1.0 200"), got[:80]
            assert idle[0].recv(10) == b""  # the first idle one was closed for it
            time.sleep(1.6)  # the other idle ones time out and free their slots
            assert s.json("/api/info")[0] == 200
        finally:
            for c in idle:
                c.close()
        assert s.server.evicted >= 1


def test_play_events_and_sessions_are_bounded_and_a_damaged_file_is_one_clear_error(study_dir):
    with Served(study_dir) as s:
        tok = s.token("P01")
        codes = [s.json("/api/event", {"token": tok, "index": 0, "type": "play"})[0] for _ in range(MAX_PLAYS + 5)]
        assert codes == [200] * MAX_PLAYS + [429] * 5
        doc = json.loads((study_dir / "responses" / "P01.json").read_text())
        assert sum(e["type"] == "play" for e in doc["history"]) == MAX_PLAYS
        assert s.json("/api/event", {"token": tok, "index": 0, "type": "x" * 10})[0] == 409
        # the answer file is damaged on disk (a crash of another tool, a bad edit)
        f = study_dir / "responses" / "P01.json"
        good = f.read_bytes()
        f.write_bytes(good[: len(good) // 2])
        for _ in range(3):
            status, err = s.json("/api/session", {"token": tok})
            assert status == 500 and "damaged" in err["error"]
        assert len([m for m in s.log if "damaged answer file" in m]) == 1  # one line, not one per request
        assert s.json("/api/session", {"token": s.token("P03")})[0] == 200  # the others go on
        f.write_bytes(good)


def test_serve_rejects_an_impossible_port(study_dir):
    p = cli("study", "serve", str(study_dir), "--port", "70000", timeout=60)
    assert p.returncode == 2 and "out of range" in p.stderr and "Traceback" not in p.stderr
