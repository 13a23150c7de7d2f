"""The README's "Python API" snippet runs as written, and ``import facecapges`` stays light."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SPEECH = REPO / "src" / "facecapges" / "assets" / "demo" / "speech.wav"


def _readme_snippet() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the README's Python API section should hold one python block"
    return blocks[0]


def test_readme_python_api_runs_as_written(tmp_path, monkeypatch):
    shutil.copy(SPEECH, tmp_path / "speech.wav")  # the snippet reads "speech.wav" from the working folder
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(_readme_snippet(), "README.md (Python API)", "exec"), scope)
    import facecapges
    from facecapges import timing

    pose, quats, gen = scope["pose"], scope["quats"], scope["gen"]
    assert pose.shape == (facecapges.N_JOINTS, 6) and np.isfinite(pose).all()
    assert quats.shape == (facecapges.N_JOINTS, 4)
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-5)
    assert gen.frames == len(timing.frame_audio(scope["audio"]))


def test_import_is_light_and_exports_the_api():
    code = ("import sys, facecapges; assert 'torch' not in sys.modules, 'torch loaded on import'; "
            "assert set(facecapges.__all__) <= set(dir(facecapges)); "
            "assert callable(facecapges.load_style) and facecapges.Stream.step and facecapges.GestureEngine; "
            "assert 'torch' not in sys.modules, 'the contract loaded torch'; "
            "facecapges.load_style(style='beat2-scott-demo'); assert 'torch' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)
