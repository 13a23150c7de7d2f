"""Shared test fixtures and the CI rule.

In CI (``CI=true``) no test may be skipped: every skip is turned into a failure (see
``pytest_runtest_makereport``), so a missing install step cannot hide behind a skip.

Real data lives in ``../shared`` beside the repository and is never copied here.
Outside CI a missing shared file skips the test that needs it; in CI (``CI=true``) it
fails the test, so a broken checkout can never pass by skipping.
"""

from __future__ import annotations

import os
import sys
from collections import Counter
from pathlib import Path

# The suite runs many tiny per-frame steps on a 2-core machine: extra intra-op threads
# only spin against each other (and against subprocesses the tests start).
os.environ.setdefault("OMP_NUM_THREADS", "1")

import signal

import pytest

# Four tests stop a `serve` / `live` subprocess with Ctrl-C (SIGINT) and check it exits
# cleanly. A suite started in the background of a script (`make test &`, nohup) inherits
# SIGINT *ignored*, which every child keeps across exec: Python then installs no
# KeyboardInterrupt handler, the commands never see the Ctrl-C, and those tests time out
# (seen in two fresh-clone runs). A handler — unlike "ignored" — is reset to the default
# on exec, so with this line the children get Ctrl-C however the suite was started.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


def shared_file(rel: str) -> Path:
    """Path of ``../shared/<rel>``; fails in CI and skips elsewhere when it is missing."""
    p = SHARED / rel
    if not p.exists():
        msg = f"shared file missing: {p}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return p


@pytest.fixture(scope="session", autouse=True)
def render_cache(tmp_path_factory) -> Path:
    """One folder per pytest session for ``render_truth``'s videos ($FACECAPGES_RENDER_CACHE, keyed by what
    decides the pixels): the truth video of 2_scott_0_1_1 is rendered once, not by test_capture_body.py,
    test_live_body.py and the bench's subprocess each. Under xdist the workers' basetemps share a parent
    (the session's), and a file lock makes the others wait for the first render (docs/testing.md)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # <session basetemp>/popen-gwN
    d = root / "render-cache"
    d.mkdir(exist_ok=True)
    os.environ["FACECAPGES_RENDER_CACHE"] = str(d)  # the tests' subprocesses inherit it
    return d


@pytest.fixture(scope="session", autouse=True)
def avatar_cache(render_cache) -> Path:
    """One folder per pytest session for the avatar's 52 ARKit targets ($FACECAPGES_AVATAR_CACHE, keyed by every
    file of the package and the face model: ``avatar.blendshapes.arkit_blendshapes``): built once (1.3-1.8 s), not
    at every ``live --web`` start, ``run`` with the avatar video and ``default_avatar`` call (docs/testing.md)."""
    d = render_cache.parent / "avatar-cache"
    d.mkdir(exist_ok=True)
    os.environ["FACECAPGES_AVATAR_CACHE"] = str(d)  # the tests' subprocesses inherit it
    return d


@pytest.fixture(scope="session")
def beat_bvh() -> Path:
    return shared_file("data/beat/2_scott_0_1_1.bvh")


@pytest.fixture(scope="session")
def beat_wav() -> Path:
    return shared_file("data/beat/2_scott_0_1_1.wav")


@pytest.fixture(scope="session")
def unseen_wav() -> Path:
    return shared_file("data/beat/2_scott_0_2_2.wav")


@pytest.fixture(scope="session")
def face_video() -> Path:
    return shared_file("data/face/WDA_KatieHill_000.mp4")


@pytest.fixture(scope="session")
def megamind_video() -> Path:
    return shared_file("data/face/Megamind.avi")


# Decoded once per session: the sample take and its speech, and the installed default style. Their
# arrays are read-only, so a test that changed them in place would fail instead of changing the next test.
@pytest.fixture(scope="session")
def beat_take(beat_bvh):
    """``read_bvh`` of the BEAT sample take (motion read-only)."""
    from facecapges.io.bvh import read_bvh

    take = read_bvh(beat_bvh)
    take.motion.setflags(write=False)
    return take


@pytest.fixture(scope="session")
def beat_audio(beat_wav):
    """``load_audio`` of the BEAT sample take's speech (16 kHz mono float32, read-only)."""
    from facecapges.io.audio import load_audio

    audio = load_audio(beat_wav)
    audio.setflags(write=False)
    return audio


@pytest.fixture(scope="session")
def default_checkpoint():
    """``load_style()`` of the installed default style, loaded once (the object ``runtime_helpers.checkpoint``
    returns, so tests using either share it); its model stays in eval mode and must not be trained in place."""
    from runtime_helpers import checkpoint

    return checkpoint()


@pytest.fixture(scope="session")
def our_vrms(tmp_path_factory, beat_bvh, beat_take):
    """Our avatar on the BEAT skeleton, built once: ``ours`` = VRM 1.0 through the command line (``avatar build
    --format vrm``), ``ours0`` = VRM 0.x by ``write_vrm`` in-process (the CLI path is the same but for
    ``--format``). The files are read-only: a test that changes one writes a copy."""
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.vrm.write import write_vrm
    from runtime_helpers import cli

    d = tmp_path_factory.mktemp("our_vrms")
    r = cli("avatar", "build", "--format", "vrm", "--skeleton", str(beat_bvh), "--out", str(d / "ours.vrm"))
    assert r.returncode == 0, r.stderr
    out = {"ours": d / "ours.vrm", "ours0": write_vrm(default_avatar(beat_take.skeleton), d / "ours0.vrm", "0.x")}
    for p in out.values():
        p.chmod(0o444)
    return out


def _read_only_tree(root: Path) -> None:
    for p in sorted(root.rglob("*"), reverse=True):
        p.chmod(0o555 if p.is_dir() else 0o444)
    root.chmod(0o555)


@pytest.fixture(scope="session")
def beat_cache(tmp_path_factory, beat_bvh):
    """``facecapges prepare <the shared BEAT folder> --speakers 2`` (the sample take; the audio-only takes
    listed as skipped), built once and read-only: tests only train and evaluate from it."""
    from runtime_helpers import cli

    out = tmp_path_factory.mktemp("beat_cache") / "c"
    r = cli("prepare", str(beat_bvh.parent), "--out", str(out), "--speakers", "2", "--quiet")
    assert r.returncode == 0, r.stderr
    _read_only_tree(out)
    return out


@pytest.fixture(scope="session")
def beat_take_cache(tmp_path_factory, beat_bvh, beat_wav):
    """``prepare()`` of a folder holding only the BEAT sample take (its BVH and WAV), built once and read-only."""
    from facecapges.data.prepare import prepare

    root = tmp_path_factory.mktemp("beat_take")
    (root / beat_bvh.name).symlink_to(beat_bvh)
    (root / beat_wav.name).symlink_to(beat_wav)
    out = tmp_path_factory.mktemp("beat_take_cache") / "c"
    prepare(root, out, progress=False)
    _read_only_tree(out)
    return out


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, the files holding a ``slow`` test run first, each file's tests kept together and in
    order: the workers start on the minute-long tests (the bench, the demo, the docs' commands, trainings) and end
    on short ones, which ``--dist worksteal`` (Makefile) shares out, so no worker is left alone with a long test
    at the end (docs/testing.md, "How long it takes"). A run without workers keeps the files' order."""
    if not hasattr(config, "workerinput"):
        return
    heavy = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in heavy)  # stable: the order within each group is kept


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """In CI nothing may be skipped: a skip there means a missing install or file."""
    outcome = yield
    report = outcome.get_result()
    if report.skipped and os.environ.get("CI", "").lower() == "true" and not hasattr(report, "wasxfail"):
        report.outcome = "failed"
        report.longrepr = f"skipped in CI (CI=true forbids skips): {report.longrepr}"


#: Modules with fuzz properties and the prefix of their counts in the summary (tests/test_fuzz.py's unprefixed).
FUZZ_MODULES = {"test_fuzz": "", "test_data_beat2": "beat2_"}


def _fuzz_cases() -> Counter:
    out: Counter = Counter()
    for name, prefix in FUZZ_MODULES.items():
        mod = sys.modules.get(name)
        if mod is not None:
            out.update({prefix + k: v for k, v in mod.CASES.items()})
    return out


# Under pytest-xdist (`make test` runs `-n 2`) the fuzz cases are counted in the workers: each sends its
# counts with its results, and the controller adds them up for the summary.
_WORKER_FUZZ_CASES: Counter = Counter()


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:
        workeroutput["fuzz_cases"] = dict(_fuzz_cases())


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    _WORKER_FUZZ_CASES.update(getattr(node, "workeroutput", {}).get("fuzz_cases", {}))


def pytest_terminal_summary(terminalreporter):
    """The number of cases the fuzz properties (tests/test_fuzz.py, the BEAT2 reader's) tried, when they ran."""
    cases = _fuzz_cases() + _WORKER_FUZZ_CASES
    if cases.total():
        terminalreporter.write_line(f"fuzz cases tried: {cases.total()} ({dict(sorted(cases.items()))})")
