"""A whole study in headless Chromium: two simulated participants click through the real page
(one closes the browser mid-study and comes back), then ``study analyze`` reproduces their answers."""

from __future__ import annotations

import base64
import json
import time
import urllib.request

import pytest

from _study_media import SYSTEMS, make_clips
from facecapges.avatar.render.browser import Browser
from facecapges.study.build import create_study, open_study
from facecapges.study.criteria import CRITERION_KEYS
from facecapges.study.server import make_server, serve_in_thread
from runtime_helpers import cli

TOKENS: dict[str, str] = {}  # participant id -> invitation token (from the study's plan)

# what each simulated participant prefers, best first
PREFER = {
    "P01": {"realism": ["ground_truth", "shift_4s", "shift_9s"], "synchrony": ["shift_4s", "ground_truth", "shift_9s"],
            "diversity": ["shift_9s", "shift_4s", "ground_truth"]},
    "P02": {"realism": ["ground_truth", "shift_9s", "shift_4s"], "synchrony": ["ground_truth", "shift_4s", "shift_9s"],
            "diversity": ["shift_4s", "shift_9s", "ground_truth"]},
}


class Page:
    """The study page in a fresh headless Chromium (the CDP driver of facecapges.avatar.render)."""

    def __init__(self, url: str):
        self.b = Browser({"/blank.json": b"{}"}, "/blank.json", 1200, 1000, timeout=90)  # then our page
        self.b.__enter__()
        self.b.call("Page.navigate", url=url)

    def close(self):
        self.b.close()

    def js(self, expr: str):
        # userGesture: a click from here counts as the user's, as a real click would (audio may start)
        r = self.b.call("Runtime.evaluate", expression=expr, awaitPromise=True, returnByValue=True, userGesture=True)
        if "exceptionDetails" in r:
            raise RuntimeError(r["exceptionDetails"])
        return r.get("result", {}).get("value")

    def wait(self, expr: str, timeout: float = 60.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            v = self.js(f"(() => {{ try {{ return {expr}; }} catch (e) {{ return null; }} }})()")
            if v:
                return v
            time.sleep(0.05)
        raise AssertionError(f"page never reached {expr}: {self.js('JSON.stringify(window.study)')}")

    def click(self, element_id: str):
        self.js(f"document.getElementById('{element_id}').click()")

    def choose(self, criterion: str, position: int, rank: int | str):
        self.js(f"(() => {{ const s = document.querySelector('select[data-criterion=\"{criterion}\"]"
                f"[data-position=\"{position}\"]'); s.value = '{rank}'; "
                "s.dispatchEvent(new Event('change', { bubbles: true })); })()")

    def ranks(self, criterion: str) -> list[str]:
        return self.js(f"[...document.querySelectorAll('select[data-criterion=\"{criterion}\"]')].map(s => s.value)")

    def screenshot(self, path):
        shot = self.b.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
        path.write_bytes(base64.b64decode(shot["data"]))

    def start(self, token: str):
        self.wait("window.study.screen === 'welcome'")
        self.js(f"document.getElementById('pid').value = '{token}'")
        self.click("start")


@pytest.fixture(scope="module")
def served(tmp_path_factory, beat_bvh, beat_wav):
    tmp = tmp_path_factory.mktemp("browser")
    # 1-s clips: the page plays each clip in real time (seven plays here), so a clip's length is the test's wait
    clips = make_clips(tmp / "src", beat_bvh, beat_wav, n_clips=3, seconds=1.0)
    create_study(clips, tmp / "study", 2, seed=3, progress=False)
    st = open_study(tmp / "study")
    TOKENS.update({p.id: p.token for p in st.plan.participants})
    server = make_server(st, "127.0.0.1", 0)
    serve_in_thread(server)
    yield tmp, st, f"http://127.0.0.1:{server.server_address[1]}/"
    server.shutdown()
    server.server_close()


def answer_elsewhere(url: str, pid: str, i: int, systems) -> None:
    """The same answer from another tab (straight to the server)."""
    ranks = {c: [PREFER[pid][c].index(s) + 1 for s in systems] for c in CRITERION_KEYS}
    body = json.dumps({"token": TOKENS[pid], "index": i, "ranks": ranks}).encode()
    req = urllib.request.Request(url + "api/answer", data=body, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=20) as r:
        assert r.status == 200


def do_trial(page: Page, st, pid: str, i: int, replay: bool = False, shot=None, other_tab: str | None = None) -> None:
    page.wait(f"window.study.ready && window.study.index === {i}")
    assert page.js("document.getElementById('progress').textContent") == f"Clip {i + 1} of 3"
    html = page.js("document.documentElement.outerHTML")
    for secret in (*SYSTEMS, *st.plan.clips):  # never labelled: no system (or clip) name on the page
        assert secret not in html
    # ranking is locked until the clip was watched to the end
    assert page.js("document.getElementById('submit').disabled")
    assert page.js("[...document.querySelectorAll('#ranking fieldset')].every(f => f.disabled)")
    page.click("play")
    page.wait("window.study.playing")
    page.wait("window.study.watched", timeout=30)
    assert page.js("window.study.frame") == 14  # played through all 15 frames (1-s clips at 15 fps)
    if replay:
        page.click("play")
        page.wait("window.study.plays === 2 && !window.study.playing", timeout=30)
    if i == 0:  # giving a rank that is taken swaps the two positions' ranks
        for j, r in enumerate((1, 2, 3)):
            page.choose("realism", j, r)
        page.choose("realism", 2, 1)
        assert page.ranks("realism") == ["3", "2", "1"]
    systems = st.plan.participant(pid).trials[i].systems
    for c in CRITERION_KEYS:
        for j, s in enumerate(systems):
            page.choose(c, j, PREFER[pid][c].index(s) + 1)
        assert page.ranks(c) == [str(PREFER[pid][c].index(s) + 1) for s in systems]
    assert not page.js("document.getElementById('submit').disabled")
    if shot is not None:
        page.screenshot(shot)
    if other_tab:  # answered in another tab first: the page's own save is refused and it moves on
        answer_elsewhere(other_tab, pid, i, systems)
    page.click("submit")


@pytest.mark.slow
def test_two_participants_complete_the_study(served):
    tmp, st, url = served
    # P01 answers the first clip, then the browser closes mid-study
    page = Page(url + f"?invite={TOKENS['P01']}")  # the invitation link
    try:
        page.wait("window.study.screen === 'welcome'")
        assert page.js("document.getElementById('pid').value") == TOKENS["P01"]
        # English by default; the participant can switch to the thesis's Chinese wording
        intro = "document.getElementById('criteria-intro').textContent"
        assert "Realism" in page.js(intro) and "真实性" not in page.js(intro)
        page.js("(() => { const s = document.getElementById('language'); s.value = 'zh'; "
                "s.dispatchEvent(new Event('change')); })()")
        assert "真实性" in page.js(intro) and "Realism" not in page.js(intro)
        page.js("(() => { const s = document.getElementById('language'); s.value = 'en'; "
                "s.dispatchEvent(new Event('change')); })()")
        page.start("P01")  # a participant id is no credential
        page.wait("document.getElementById('start-error').textContent.includes('unknown invitation')")
        page.start(TOKENS["P01"])
        do_trial(page, st, "P01", 0, shot=tmp / "trial.png")
        page.wait("window.study.index === 1 && window.study.ready")
    finally:
        page.close()
    saved = json.loads((tmp / "study" / "responses" / "P01.json").read_text())
    assert [e["trial"] for e in saved["history"] if e["type"] == "answer"] == [0]
    # … and comes back: the same id resumes at clip 2
    page = Page(url)
    try:
        page.start(TOKENS["P01"])
        do_trial(page, st, "P01", 1)
        do_trial(page, st, "P01", 2)
        page.wait("window.study.screen === 'done'")
    finally:
        page.close()
    page = Page(url)
    try:
        page.start(TOKENS["P02"])
        for i in range(3):
            do_trial(page, st, "P02", i, replay=(i == 1), other_tab=url if i == 1 else None)
        page.wait("window.study.screen === 'done'")
    finally:
        page.close()
    page = Page(url)  # coming back after the end shows the thank-you page, no clip
    try:
        page.start(TOKENS["P02"])
        page.wait("window.study.screen === 'done'")
        assert page.js("window.study.index") == -1
    finally:
        page.close()
    assert (tmp / "trial.png").stat().st_size > 20_000

    p2 = json.loads((tmp / "study" / "responses" / "P02.json").read_text())
    plays = [e["trial"] for e in p2["history"] if e["type"] == "play"]
    assert plays == [0, 1, 1, 2]

    out = tmp / "results"
    res = cli("study", "analyze", str(tmp / "study"), "--out", str(out), timeout=120)
    assert res.returncode == 0, res.stderr
    results = json.loads((out / "results.json").read_text())
    assert results["n_participants"] == 2 and results["n_answers"] == 6
    for c in CRITERION_KEYS:
        for s in SYSTEMS:
            want = (PREFER["P01"][c].index(s) + PREFER["P02"][c].index(s)) / 2 + 1
            got = results["criteria"][c]["systems"][s]
            assert got["mean_rank"] == pytest.approx(want), (c, s)
            counts = [0, 0, 0]
            for pid in PREFER:
                counts[PREFER[pid][c].index(s)] += 3
            assert got["rank_counts"] == counts
    assert (out / "mean_rank.png").is_file() and (out / "rank_shares.png").is_file()
    # one participant alone (like thesis fig. 5.3 beside 5.2): exactly that participant's ranks
    res = cli("study", "analyze", str(tmp / "study"), "--out", str(tmp / "p02"), "--only", "p02", timeout=120)
    assert res.returncode == 0, res.stderr
    alone = json.loads((tmp / "p02" / "results.json").read_text())
    assert alone["participants"] == ["P02"] and alone["n_answers"] == 3
    assert alone["criteria"]["diversity"]["systems"]["shift_4s"]["mean_rank"] == 1.0
