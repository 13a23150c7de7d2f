"""The examples in docs/ run as written, against the real programs."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

from runtime_helpers import cli_process

ROOT = Path(__file__).resolve().parents[1]
DEMO_WAV = ROOT / "src" / "facecapges" / "assets" / "demo" / "speech.wav"


def test_serve_client_example_streams_against_a_real_server():
    """docs/examples/serve_client.py against `facecapges serve` with the installed default style."""
    proc = cli_process("serve", "--port", "0", background=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("serving"), line + proc.stderr.read()
        url = line.split(" on ")[1].split()[0]
        res = subprocess.run([sys.executable, str(ROOT / "docs" / "examples" / "serve_client.py"), url,
                              str(DEMO_WAV), "--seconds", "2"], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        lines = res.stdout.splitlines()
        assert lines[-1] == "30 frames"
        frames = [int(x.split()[1]) for x in lines[:-1]]
        assert frames == list(range(30))  # every frame back, in order
        assert all("RightForeArm w=" in x for x in lines[:-1])
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)


# ----------------------------------------------------------------------------------------------------------------
# Every command block of README.md and docs/*.md: each command either runs here (on ../shared data, shortened the
# documented way) or is listed below with the reason it cannot; a new command in the docs that is neither fails
# test_every_doc_command_is_run_or_has_a_reason, so the docs cannot drift from the programs.

import re  # noqa: E402
import shlex  # noqa: E402

import pytest  # noqa: E402

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FULL_BEAT = "needs the full BEAT data set (hours of each speaker) at /data/beat_english_v0.2.1"
# (doc file, the start of the command) → why it cannot run here
CANNOT_RUN: dict[tuple[str, str], str] = {
    ("README.md", "make demo"): "the whole install and demo; tests/test_demo.py runs the demo",
    ("README.md", "make test"): "the test suite itself",
    ("README.md", "facecapges live --camera 0"): "a webcam and a microphone",
    ("README.md", "facecapges styles build me --video me.mp4"):
        "the reader's own video of themselves talking (tests/test_capture_body.py captures a rendered one)",
    ("README.md", "facecapges capture-body me.mp4"): "the reader's own video (same test)",
    ("capture-body.md", "facecapges capture-body me_talking.mp4"): "the reader's own video (same test)",
    ("capture-body.md", "facecapges live --camera 0"): "a webcam and a microphone",
    ("capture-body.md", "facecapges live --video me.mp4"):
        "the reader's own video and speech (tests/test_live_body.py runs live --body on a rendered one)",
    ("capture-body.md", "python -m facecapges.evaluation.body_capture"):
        "renders and captures the held-out end of two takes (minutes); tests/test_capture_body.py runs its measure on 1_1",
    ("capture-body.md", "facecapges styles build vid11 --video train11.mp4"):
        "the record of one measurement: a style built (minutes) from a render of 1_1's training 80 % made for it",
    ("capture-body.md", "PYTHONPATH=src nice -n 10 .venv/bin/python scripts/conversation_report.py"):
        "the conversation report of that style and the default (minutes each); "
        "tests/test_matching_conversation.py covers its figures",
    ("capture-body.md", "python scripts/conversation_report.py --table"): "the table of the two reports above",
    ("ablation_beat2_scott.md", "facecapges prepare <folder"): "the record of the ablation's own runs (hours of training)",
    ("ablation_beat2_scott.md", "facecapges ablate"): "an ablation: trains every variant (hours)",
    ("ablation_beat2_scott.md", "facecapges prepare ../shared/data/beat --out build/default-style/cache"):
        "the record of the ablation's own runs (its cache feeds the hour-long ablate below it)",
    ("bring-your-own-mocap.md", "facecapges prepare path/to/"): "the reader's own BEAT folder and mocap",
    ("bring-your-own-mocap.md", "facecapges train --cache cache --speaker 101"): "the cache of the reader's own mocap",
    ("serve-protocol.md", "facecapges serve"):
        "a server left running; test_serve_client_example_streams_against_a_real_server runs it with the client",
    ("serve-protocol.md", "python docs/examples/serve_client.py"): "the client of the server above (same test)",
    ("serve-cluster.md", "pip install -e"): "an install step (make setup installs the ray extra)",
    ("serve-cluster.md", "ray start --head"): "a Ray cluster's head left running; tests/test_serve_ray.py starts one",
    ("serve-cluster.md", "ray start --address"): "a worker machine joining that head (same test)",
    ("serve-cluster.md", "facecapges serve --ray"): "a server on the cluster left running (same test)",
    ("train-your-own-style.md", "facecapges prepare /data/"): FULL_BEAT,
    ("train-your-own-style.md", "facecapges train --cache cache/beat"): FULL_BEAT,
    ("train-your-own-style.md", "facecapges fgd-train --cache cache/beat"): FULL_BEAT,
    ("train-your-own-style.md", "facecapges eval --cache cache/beat"): FULL_BEAT,
    ("train-your-own-style.md", "facecapges generate --audio speech.wav --out scott.bvh"): FULL_BEAT,
    ("user-study.md", "facecapges study create"): "the reader's CLIPS.yaml of their own clips",
    ("user-study.md", "facecapges study serve"): "a server for participants on the network",
    ("user-study.md", "facecapges study analyze"): "participants' answers",
}
# The documented ways to shorten a run (each command's --help): appended where the command starts so.
SHORTER = {
    "facecapges train ": ["--epochs", "1"],
    "facecapges fgd-train ": ["--epochs", "2"],
    "facecapges eval ": ["--no-video", "--samples", "1"],
    "facecapges styles build ": ["--steps", "10"],
}


def doc_commands(path: Path) -> list[str]:
    """The commands of ``path``'s ```sh blocks: continuation lines joined, comments and ``[optional …]`` parts
    dropped, ``.venv/bin/``, ``$F`` and ``OMP_NUM_THREADS=1 nice -n 10`` prefixes read as the command."""
    out: list[str] = []
    variables: dict[str, str] = {}  # F=.venv/bin/facecapges in one block serves the page's later blocks
    for block in re.findall(r"```sh\n(.*?)```", path.read_text(encoding="utf-8"), re.S):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = re.sub(r"(^|\s+)#.*$", "", line).strip()
            line = re.sub(r"\s*\[[^\]]*\]", "", line)
            m = re.fullmatch(r"([A-Z]+)=(\S+)", line)
            if m:
                variables[m.group(1)] = m.group(2)
                continue
            for k, v in variables.items():
                line = line.replace(f"${k}", v)
            line = re.sub(r"^(OMP_NUM_THREADS=\d+\s+)?(nice -n \d+\s+)?", "", line)
            line = re.sub(r"^\.venv/bin/", "", line)
            if line:
                out.append(line)
    return out


def _reason(doc: str, command: str) -> str | None:
    return next((why for (d, start), why in CANNOT_RUN.items() if d == doc and command.startswith(start)), None)


def _runnable() -> list[tuple[str, str]]:
    return [(p.name, c) for p in DOCS for c in doc_commands(p) if _reason(p.name, c) is None]


def test_every_doc_command_is_run_or_has_a_reason():
    """Each command is one the runner below can start (facecapges or python), or is listed with its reason; every
    listed reason still matches a command (a command renamed in the docs is not silently dropped)."""
    commands = [(p.name, c) for p in DOCS for c in doc_commands(p)]
    assert len(commands) > 30
    odd = [(d, c) for d, c in _runnable() if not c.startswith("facecapges ")]
    assert not odd, odd
    unused = [k for k in CANNOT_RUN if not any(d == k[0] and c.startswith(k[1]) for d, c in commands)]
    assert not unused, unused


def _short_shared(dest: Path, unseen: str = "data/beat/2_scott_0_4_4.wav", seconds: int = 10) -> None:
    """``dest`` laid out as ../shared: links to the real one's files, but the unseen speech the docs generate and
    evaluate on (``unseen``, 67 s) is its first ``seconds`` s (the folders on its path are folders of links)."""
    import os

    from conftest import SHARED, shared_file
    from facecapges.io.audio import load_audio, save_audio

    speech = load_audio(shared_file(unseen))[: seconds * 16000]  # first: a missing file fails in CI, else skips
    cut = Path(unseen)
    folders = [Path(), *reversed(cut.parents[:-1])]  # "", "data", "data/beat"
    for rel in folders:
        (dest / rel).mkdir(parents=True, exist_ok=True)
        for entry in (SHARED / rel).iterdir():
            if rel / entry.name not in (*folders, cut):
                os.symlink(entry, dest / rel / entry.name)
    save_audio(dest / cut, speech)


def _sandbox(tmp: Path) -> Path:
    """A folder laid out as the repository's root for the docs' relative paths: ../shared beside it, configs/,
    and the inputs the docs name as the reader's (a speech clip, a ZEGGS take as "your" mocap), all short."""
    import os
    import shutil

    from conftest import shared_file
    from facecapges import timing
    from facecapges.io.audio import load_audio, save_audio
    from facecapges.io.bvh import read_bvh, write_bvh

    repo = tmp / "repo"
    (repo / "src" / "facecapges" / "assets" / "demo").mkdir(parents=True)
    _short_shared(tmp / "shared")
    os.symlink(ROOT / "configs", repo / "configs")
    seconds = 16
    speech = load_audio(DEMO_WAV)[: 3 * timing.AUDIO_SR]  # the README renders its demo.bvh: 3 s, 45 frames
    for name in ("src/facecapges/assets/demo/speech.wav", "talk.wav", "talk1.wav"):
        save_audio(repo / name, speech)
    z = read_bvh(shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"))
    zwav = load_audio(shared_file("data/zeggs/067_Speech_2_x_1_0.wav"))[: seconds * timing.AUDIO_SR]
    (repo / "mocap").mkdir()
    for stem in ("my_take", "take", "mocap/talk1"):
        write_bvh(repo / f"{stem}.bvh", z.skeleton, z.motion[: int(seconds * z.fps)], z.fps)
        save_audio(repo / f"{stem}.wav", zwav)
    shutil.copy(shared_file("data/zeggs/LICENSE-ZEGGS.md"), repo / "LICENSE-ZEGGS.md")  # as ZEGGS comes
    return repo


@pytest.mark.slow
def test_doc_commands_run_as_written(tmp_path):
    """Every runnable command of README.md and docs/*.md, in the order of its document, in a folder laid out like
    the repository (inputs the docs leave to the reader are short real clips), shortened by SHORTER."""
    import os

    from runtime_helpers import cli_process_sequence

    repo = _sandbox(tmp_path)
    os.makedirs(repo / "out", exist_ok=True)
    plan: list[tuple[str, ...]] = [("generate", "--audio", "src/facecapges/assets/demo/speech.wav", "--out",
                                    "out/demo.bvh")]  # what `make demo` leaves in out/ for the README's render
    for _doc, command in _runnable():
        words = shlex.split(command)[1:]
        for start, extra in SHORTER.items():
            if command.startswith(start):
                words += extra
        plan.append(tuple(words))
    env_styles = str(tmp_path / "styles")
    old = dict(os.environ)
    os.environ["FACECAPGES_STYLES"] = env_styles
    cwd = os.getcwd()
    try:
        os.chdir(repo)
        results = cli_process_sequence(*plan, timeout=600)
    finally:
        os.chdir(cwd)
        os.environ.clear()
        os.environ.update(old)
    failed = [(" ".join(r.args[1:]), r.stderr[-600:]) for r in results if r.returncode != 0]
    assert not failed, failed
    assert (repo / "me.mp4").stat().st_size > 10_000 and (repo / "talk.vrma").is_file()
    assert (tmp_path / "styles" / "me.safetensors").is_file() and (tmp_path / "styles" / "scott-here.safetensors").is_file()
