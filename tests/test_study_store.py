"""The answer store and the study server over HTTP: order, blindness, nothing lost on a close or crash."""

from __future__ import annotations

import json
import os
import threading
import urllib.error
import urllib.request

import pytest

from _study_media import SYSTEMS, make_clips
from facecapges.study import store as store_mod
from facecapges.study.build import create_study, open_study
from facecapges.study.design import make_plan
from facecapges.study.server import make_server, serve_in_thread
from facecapges.study.store import AnswerError, AnswerStore

GOOD = {"realism": [1, 2, 3], "synchrony": [3, 1, 2], "diversity": [2, 3, 1]}


@pytest.fixture
def plan():
    return make_plan(["a", "b", "c"], ["x", "y", "z"], 6, seed=2)


def test_answers_in_order_survive_a_closed_session(tmp_path, plan):
    s = AnswerStore(tmp_path, plan)
    assert s.session("P02") == {"participant": "P02", "next": 0, "total": 3, "done": False}
    s.event("P02", 0, "play")
    s.answer("P02", 0, GOOD)
    before = json.loads((tmp_path / "P02.json").read_text())["history"]
    # the browser closes; later the same participant comes back (a new store = a restarted server)
    s2 = AnswerStore(tmp_path, plan)
    assert s2.session("P02")["next"] == 1
    after = json.loads((tmp_path / "P02.json").read_text())["history"]
    assert after[: len(before)] == before  # append-only
    ans = [e for e in after if e["type"] == "answer"]
    t0 = plan.participant("P02").trials[0]
    assert ans[0]["clip"] == t0.clip and ans[0]["positions"] == list(t0.systems)
    assert ans[0]["ranks"]["synchrony"] == dict(zip(t0.systems, [3, 1, 2]))
    with pytest.raises(AnswerError, match="not the current trial"):
        s2.answer("P02", 0, GOOD)  # no going back
    with pytest.raises(AnswerError, match="not the current trial"):
        s2.answer("P02", 2, GOOD)  # no skipping
    s2.answer("P02", 1, GOOD)
    s2.answer("P02", 2, GOOD)
    assert s2.state("P02")["done"]
    with pytest.raises(AnswerError, match="already been ranked"):
        s2.answer("P02", 3, GOOD)
    assert not (tmp_path / "P01.json").exists()


@pytest.mark.parametrize("ranks", [
    {"realism": [1, 1, 3], "synchrony": [1, 2, 3], "diversity": [1, 2, 3]},
    {"realism": [1, 2], "synchrony": [1, 2, 3], "diversity": [1, 2, 3]},
    {"realism": [1, 2, 3], "synchrony": [1, 2, 3]},
    {"realism": [0, 1, 2], "synchrony": [1, 2, 3], "diversity": [1, 2, 3]},
    {"realism": [True, 2, 3], "synchrony": [1, 2, 3], "diversity": [1, 2, 3]},
    {"realism": ["1", "2", "3"], "synchrony": [1, 2, 3], "diversity": [1, 2, 3]},
    [1, 2, 3],
])
def test_malformed_ranks_are_refused(tmp_path, plan, ranks):
    s = AnswerStore(tmp_path, plan)
    with pytest.raises(AnswerError):
        s.answer("P01", 0, ranks)
    assert s.state("P01")["next"] == 0


def test_a_crash_while_writing_loses_nothing_already_saved(tmp_path, plan, monkeypatch):
    s = AnswerStore(tmp_path, plan)
    s.answer("P01", 0, GOOD)
    saved = (tmp_path / "P01.json").read_bytes()

    def die(*args):
        raise OSError("power cut")

    monkeypatch.setattr(store_mod.os, "replace", die)
    with pytest.raises(OSError):
        s.answer("P01", 1, GOOD)
    monkeypatch.undo()
    assert (tmp_path / "P01.json").read_bytes() == saved  # the old complete file, not a torn one
    assert sorted(os.listdir(tmp_path)) == ["P01.json"]  # no temporary left behind
    assert AnswerStore(tmp_path, plan).state("P01")["next"] == 1
    s.answer("P01", 1, GOOD)
    assert s.state("P01")["next"] == 2


def test_concurrent_double_submit_saves_once(tmp_path, plan):
    s = AnswerStore(tmp_path, plan)
    ok, refused = [], []

    def submit():
        try:
            s.answer("P03", 0, GOOD)
            ok.append(1)
        except AnswerError:
            refused.append(1)

    threads = [threading.Thread(target=submit) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(ok) == 1 and len(refused) == 7
    assert s.state("P03")["next"] == 1


# ---------------------------------------------------------------------------- over HTTP
@pytest.fixture(scope="module")
def study(tmp_path_factory, beat_bvh, beat_wav):
    tmp = tmp_path_factory.mktemp("study")
    y = make_clips(tmp / "src", beat_bvh, beat_wav, n_clips=2, seconds=2.0)
    create_study(y, tmp / "study", 3, seed=11, progress=False)
    return tmp / "study"


class Client:
    def __init__(self, study_dir):
        self.study = open_study(study_dir)
        self.server = make_server(self.study, "127.0.0.1", 0)
        serve_in_thread(self.server)
        self.base = f"http://127.0.0.1:{self.server.server_address[1]}"

    def close(self):
        self.server.shutdown()
        self.server.server_close()

    def req(self, path, body=None):
        data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
        r = urllib.request.Request(self.base + path, data=data, headers={"Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(r, timeout=20) as resp:
                return resp.status, resp.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()

    def json(self, path, body=None):
        status, raw = self.req(path, body)
        return status, json.loads(raw)


def test_server_flow_is_blind_ordered_and_resumable(study):
    c = Client(study)
    try:
        status, page = c.req("/")
        assert status == 200 and b"Gesture study" in page
        status, info = c.json("/api/info")
        assert status == 200 and info["versions"] == 3 and info["clips"] == 2
        assert [k["key"] for k in info["criteria"]] == ["realism", "synchrony", "diversity"]
        assert "真实性" in json.dumps(info, ensure_ascii=False)
        tok = c.study.plan.participant("P02").token
        status, err = c.json("/api/session", {"participant": "P02"})  # an id alone is no credential
        assert status == 401 and "invitation" in err["error"]
        status, err = c.json("/api/session", {"token": "P02"})
        assert status == 401 and "unknown invitation" in err["error"]
        status, st = c.json("/api/session", {"token": f" {tok} "})
        assert status == 200 and st == {"participant": "P02", "next": 0, "total": 2, "done": False}
        assert c.json(f"/api/trial?token={tok}&index=1")[0] == 409
        status, trial = c.json(f"/api/trial?token={tok}&index=0")
        assert status == 200 and trial["frames"] == 30 and len(trial["motions"]) == 3
        plan_trial = c.study.plan.participant("P02").trials[0]
        seen = [json.dumps(info), json.dumps(trial), page.decode()]
        for j, url in enumerate(trial["motions"]):
            status, raw = c.req(url)
            want = (study / "media" / plan_trial.clip / f"motion-{plan_trial.systems[j]}.json").read_bytes()
            assert status == 200 and raw == want  # position j plays the planned system
            seen.append(url)
        status, wav = c.req(trial["audio"])
        assert status == 200 and wav[:4] == b"RIFF"
        for secret in [*SYSTEMS, plan_trial.clip]:  # nothing the page receives names a system or clip
            assert all(secret not in s for s in seen), secret
        assert c.req(trial["motions"][0].replace("motion-0", "motion-3"))[0] == 404
        assert c.req(f"/media/{tok}/1/audio.wav")[0] == 409
        assert c.req("/media/P02/0/audio.wav")[0] == 401
        assert c.req("/three/../../../etc/passwd")[0] == 404
        assert c.req("/page/../server.py")[0] == 404
        status, err = c.json("/api/answer", {"token": tok, "index": 0, "ranks": {"realism": [1, 1, 2]}})
        assert status == 409 and "criteria" in err["error"]
        status, st = c.json("/api/answer", {"token": tok, "index": 0, "ranks": GOOD})
        assert status == 200 and st["next"] == 1
        # saved before the reply: the file already holds the answer
        doc = json.loads((study / "responses" / "P02.json").read_text())
        assert [e["trial"] for e in doc["history"] if e["type"] == "answer"] == [0]
        assert c.req(trial["motions"][0])[0] == 409  # no going back to clip 1
        status, err = c.json("/api/session", b"not json")
        assert status == 400 and err["error"] == "request body is not JSON"
    finally:
        c.close()
    # the server stops (or the browser closes) mid-study; a new server resumes the participant
    c = Client(study)
    try:
        tok = c.study.plan.participant("P02").token
        status, st = c.json("/api/session", {"token": tok})
        assert st["next"] == 1 and not st["done"]
        status, st = c.json("/api/answer", {"token": tok, "index": 1, "ranks": GOOD})
        assert st["done"]
        assert c.json(f"/api/trial?token={tok}&index=2")[0] == 409
    finally:
        c.close()
