"""Our exported BVH opens in three.js: parsed by three's own BVHLoader (node)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.skeleton import motion_to_pose, pose_to_motion

REPO = Path(__file__).resolve().parents[1]


def test_exported_bvh_parses_in_threejs(tmp_path, beat_bvh):
    node = shutil.which("node")
    if node is None or not (REPO / "node_modules" / "three").is_dir():
        pytest.fail("node and node_modules/three are installed by `make setup`")
    src = read_bvh(beat_bvh)
    pose, _ = motion_to_pose(src.skeleton, src.motion)
    out = write_bvh(tmp_path / "export.bvh", src.skeleton, pose_to_motion(src.skeleton, pose), 15)
    p = subprocess.run([node, str(REPO / "scripts" / "check-bvh-three.mjs"), str(out)], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    joints = [n for n in info["names"] if n != "ENDSITE"]
    assert joints == src.skeleton.names  # all 75 joints, in order
    assert info["duration"] == pytest.approx((src.n_frames - 1) / 15, abs=1e-3)
    assert info["tracks"] > 47  # rotation tracks for every joint (+ root position)
