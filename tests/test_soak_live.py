"""The short version of the live soak (scripts/soak_live.py): 18 s of unseen speech with pauses, in real time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_soak_audio_has_the_pauses_it_says(face_video, unseen_wav):
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import soak_live
    finally:
        sys.path.pop(0)
    audio, pauses = soak_live.soak_audio(120.0, (2.0, 30.0), seed=3)
    assert len(audio) == 120 * 16000 and pauses
    for a, b, kind in pauses:
        seg = audio[int(a * 16000) + 1 : int(b * 16000) - 1]
        assert 2.0 - 1e-6 <= b - a <= 30.0 or b >= 119.9
        if kind == "zeros":
            assert not np.any(seg)
        else:  # room tone: quiet but not digital silence
            assert 0 < np.sqrt(np.mean(seg**2)) < 0.01
    assert {k for *_, k in pauses} == {"zeros", "room tone"} or len(pauses) == 1


@pytest.mark.slow
def test_short_soak(tmp_path, face_video, unseen_wav):
    out = tmp_path / "soak"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "soak_live.py"),
            "--minutes",
            "0.3",  # 18 s; seed 11 puts both kinds of pause in them: zeros at 6.1-10.5 s, room tone at 14.9-17.5 s
            "--seed",
            "11",
            "--pause-range",
            "2",
            "6",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=1200,
    )
    assert r.returncode == 0, r.stderr[-3000:] + r.stdout[-3000:]
    fig = json.loads((out / "soak.json").read_text())
    assert fig["frames"] == fig["frames_expected"] == 270 and fig["stopped_by"] == "end of input"
    assert fig["pauses"] == 2 and fig["pause_minutes"] > 0 and fig["speech_minutes"] > 0
    for k in ("pops_per_min", "pops_per_min_in_pauses", "pops_per_min_in_speech", "rss_mb_max"):
        assert np.isfinite(fig[k]), k
    assert fig["rss_mb_end"] < 3000  # the whole live process, model and face capture included
    assert fig["threshold_rad_s2"] > 0 and "late_frames" in fig and fig["drift_ms_last"] is not None
    assert (out / "record" / "motion.bvh").stat().st_size > 10_000
