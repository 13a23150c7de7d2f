"""``live --record`` writes its BVH as it goes (valid at every moment) and SIGTERM/SIGHUP close
the recording cleanly, like Ctrl-C (bounded: a few seconds of a real video on loopback)."""

from __future__ import annotations

import json
import signal
import time

import pytest

from facecapges.io.bvh import read_bvh
from facecapges.io.face_json import read_face_json
from runtime_helpers import cli_popen


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_leaves_whole_recordings(face_video, tmp_path, sig):
    rec = tmp_path / "rec"
    proc = cli_popen("live", "--video", str(face_video), "--realtime", "--loop", "--record", str(rec),
                     "--max-seconds", "120")
    try:
        deadline = time.time() + 90
        grown = 0
        while time.time() < deadline and grown < 30:  # the BVH grows while live runs, valid each time
            time.sleep(1.0)
            if (rec / "motion.bvh").is_file():
                grown = read_bvh(rec / "motion.bvh").motion.shape[0]
        assert grown >= 30, proc.stderr.read()[-2000:] if proc.poll() is not None else "no frames recorded"
        proc.send_signal(sig)
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "Traceback" not in err, err[-2000:]
    rep = json.loads((rec / "report.json").read_text())
    n = read_bvh(rec / "motion.bvh").motion.shape[0]
    assert rep["stopped_by"] == "interrupted" and n == rep["frames"] >= grown
    face = read_face_json(rec / "face.json")  # the same length (whatever rate the face JSON is written at)
    assert face.n_frames / face.fps == pytest.approx(n / 15, abs=1 / 15)
