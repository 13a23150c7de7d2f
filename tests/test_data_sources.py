"""One cache of BEAT + the retargeted ZEGGS take + the 9-joint takes; its exports play in Blender and three.js."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_file
from facecapges.data.cache import Cache
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY, joint_positions
from runtime_helpers import cli

REPO = Path(__file__).resolve().parents[1]
ZEGGS = "zeggs_067_Speech_2_x_1_0"
BONES = ["RightHand", "LeftForeArm", "RightHandIndex3", "LeftHandThumb3"]

BLENDER_SCRIPT = '''
import builtins, json, sys
_open = builtins.open
builtins.open = lambda f, mode="r", *a, **k: _open(f, mode.replace("U", ""), *a, **k)  # Debian 3.4: mode 'rU'
import bpy
path, frames, bones, out = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.import_anim.bvh(filepath=path, global_scale=1.0, frame_start=1, use_fps_scale=False, rotate_mode="NATIVE",
                        axis_forward="-Z", axis_up="Y")
obj = bpy.context.selected_objects[0]
res = {}
for f in map(int, frames.split(",")):
    bpy.context.scene.frame_set(f)
    res[str(f)] = {b: list(obj.matrix_world @ obj.pose.bones[b].head) for b in bones.split(",")}
_open(out, "w").write(json.dumps(res))
'''


def run(*args):
    return cli(*map(str, args))


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    out = tmp_path_factory.mktemp("sources") / "cache"
    res = run("prepare", shared_file("data/beat/2_scott_0_1_1.bvh").parent, "--speakers", "2", "--out", out,
              "--mocap", shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"),
              "--joints9", shared_file("data/zeggs9/001_Neutral_0_x_1_0.npy").parent, "--quiet")
    assert res.returncode == 0, res.stderr
    return Cache(out), res.stdout


def test_one_cache_holds_every_source(cache):
    c, stdout = cache
    by = {e["name"]: e for e in c.clips()}
    assert set(by) == {"2_scott_0_1_1", ZEGGS, "zeggs9_001_Neutral_0_x_1_0", "zeggs9_003_Neutral_2_x_1_0"}
    assert (by["2_scott_0_1_1"]["speaker"], by["2_scott_0_1_1"]["origin"]) == (2, "beat")
    assert (by[ZEGGS]["speaker"], by[ZEGGS]["origin"], by[ZEGGS]["n_frames"]) == (100, "retarget", 1033)
    assert by["zeggs9_001_Neutral_0_x_1_0"]["n_frames"] == len(np.load(shared_file(
        "data/zeggs9/001_Neutral_0_x_1_0.npy"), mmap_mode="r")[::4])
    assert c.speakers == [2, 100]
    assert c.speaker_info(100)["licence"] == "CC BY-NC-ND 4.0" and c.speaker_info(2)["licence"] == "CC BY-NC 4.0"
    for e in c.clips():
        a = c.load(e["name"])
        T = e["n_frames"]
        assert a["pose"].shape == (T, 47, 6) and a["mask"].shape == (47,) and a["audio"].shape == (int(T * 16000 / 15),)
        assert e["holdout_from"] == int(T * 0.8)
        assert int((~a["mask"]).sum()) == e["n_masked"]
    assert c.load("2_scott_0_1_1")["mask"].all()
    assert c.load(ZEGGS)["mask"].sum() == 41 and c.load("zeggs9_003_Neutral_2_x_1_0")["mask"].sum() == 9
    assert "4 clips" in stdout and "100" in stdout
    # the statistics of a joint come only from clips that have it
    s100 = c.stats(100)
    k = UPPER_BODY.index("RightHandIndex")
    assert np.allclose(s100["pose_std"][k], 1.0) and np.allclose(s100["pose_mean"][k], 0.0)


def test_masked_joints_hold_the_fill(cache):
    c, _ = cache
    a = c.load(ZEGGS)
    fill = np.asarray(c.index["fill"], np.float32).reshape(47, 6)
    assert np.allclose(a["pose"][:, ~a["mask"]], fill[~a["mask"]], atol=1e-5)


@pytest.fixture(scope="module")
def exported(cache, tmp_path_factory):
    c, _ = cache
    out = tmp_path_factory.mktemp("export") / "zeggs.bvh"
    res = run("export", c.path, "--clip", ZEGGS, "--out", out)
    assert res.returncode == 0, res.stderr
    bvh = read_bvh(out)
    return out, bvh, joint_positions(bvh.skeleton, bvh.motion)


def test_export_moves_arms_and_fingers(exported):
    _out, bvh, P = exported
    src = read_bvh(shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"))
    assert bvh.fps == 15 and bvh.n_frames == 1033 and bvh.skeleton.n_joints == 75
    assert np.ptp(P[:, bvh.skeleton.index("RightHandIndex3")], axis=0).max() > 10  # the fingers travel (cm)
    assert src.skeleton.n_joints == 75 and bvh.skeleton.names != src.skeleton.names
    # the cache's fill of the masked metacarpals keeps every measured bone pointing where the retarget put it
    from facecapges.data.retarget import retarget_bvh
    from facecapges.skeleton import pose_to_motion

    direct = retarget_bvh(shared_file("data/zeggs/067_Speech_2_x_1_0.bvh"), bvh.skeleton, fps=15)
    Pd = joint_positions(bvh.skeleton, pose_to_motion(bvh.skeleton, direct.pose))
    for a, b in (("RightHandIndex1", "RightHandIndex2"), ("LeftHandPinky2", "LeftHandPinky3"),
                 ("RightForeArm", "RightHand")):
        ia, ib = bvh.skeleton.index(a), bvh.skeleton.index(b)
        u, v = P[:, ib] - P[:, ia], Pd[:, ib] - Pd[:, ia]
        cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.1, (a, b)


@pytest.mark.slow
def test_export_plays_in_blender(exported, tmp_path):
    blender = shutil.which("blender")
    if blender is None:
        pytest.fail("Debian's blender is installed by `make setup`")
    out, bvh, P = exported
    script = tmp_path / "import_bvh.py"
    script.write_text(BLENDER_SCRIPT)
    res = subprocess.run([blender, "-b", "--factory-startup", "--python", str(script), "--", str(out), "1,400,1000",
                          ",".join(BONES), str(tmp_path / "pose.json")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and (tmp_path / "pose.json").is_file(), res.stdout[-2000:] + res.stderr[-2000:]
    got = json.loads((tmp_path / "pose.json").read_text())
    for f, bones in got.items():
        for b, xyz in bones.items():
            x, y, z = P[int(f) - 1, bvh.skeleton.index(b)]
            assert np.allclose(xyz, [x, -z, y], atol=0.05), (f, b, xyz)  # Blender: Z up, BVH's −Z forward


def test_export_plays_in_threejs(exported):
    node = shutil.which("node")
    if node is None or not (REPO / "node_modules" / "three").is_dir():
        pytest.fail("node and node_modules/three are installed by `make setup`")
    out, bvh, P = exported
    frames = [0, 399, 999]
    res = subprocess.run([node, str(REPO / "scripts" / "bvh-three-pose.mjs"), str(out),
                          ",".join(str(f / 15) for f in frames), ",".join(BONES)], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout)
    for f, bones in zip(frames, got.values()):
        for b, xyz in bones.items():
            assert np.allclose(xyz, P[f, bvh.skeleton.index(b)], atol=0.05), (f, b)


def test_speaker_ids_of_other_sources(tmp_path):
    from facecapges.data.prepare import prepare
    from facecapges.errors import UserError

    beat_bvh, beat_wav = shared_file("data/beat/2_scott_0_1_1.bvh"), shared_file("data/beat/2_scott_0_1_1.wav")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "take1.bvh").symlink_to(beat_bvh)  # BEAT's names, as someone's own capture would have them
    (mine / "take1.wav").symlink_to(beat_wav)
    with pytest.raises(UserError, match="states no speaker id"):
        prepare(None, tmp_path / "c", mocap=[mine], target=read_bvh(beat_bvh).skeleton, progress=False)
    with pytest.raises(UserError, match="BEAT's range"):
        prepare(None, tmp_path / "c", mocap=[mine], mocap_speaker=2, target=read_bvh(beat_bvh).skeleton,
                progress=False)
    index = prepare(None, tmp_path / "c", mocap=[mine], mocap_speaker=101, target=read_bvh(beat_bvh).skeleton,
                    progress=False)
    (clip,) = index["clips"]
    assert (clip["name"], clip["speaker"], clip["joint_map"], clip["n_masked"]) == ("beat_take1", 101, "beat", 0)
    (mine / "take2.bvh").symlink_to(beat_bvh)  # no take2.wav
    with pytest.raises(UserError, match=r"take2\.wav"):
        prepare(None, tmp_path / "c2", mocap=[mine], mocap_speaker=101, target=read_bvh(beat_bvh).skeleton,
                progress=False)
