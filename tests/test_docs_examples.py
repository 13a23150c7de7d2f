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
