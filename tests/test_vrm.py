"""VRM out, VRM in, VRM Animation — checked with the VRM schemas, Khronos' validator and three-vrm.

* Our avatar as VRM 1.0 (``avatar build --format vrm``): the ``VRMC_vrm`` extension against
  the schemas of the VRM specification (tests/vrm_schemas.py), the Khronos glTF validator,
  and ``@pixiv/three-vrm`` in headless Chromium (bones, expressions bound to morphs).
* Four avatars — ours, a long-armed VRM 1.0 with rotated bone frames, a VRM 0.x facing −Z
  and an A-pose Mixamo-named GLB (tests/vrm_samples.py, built here with pygltflib) — driven
  by BEAT motion through three-vrm: each arm segment must point where BEAT's forward
  kinematics says (world space, from the three-vrm scene graph) and, on the samples, the
  coloured hands must appear where BEAT says in a screenshot.
* The same motion as ``.vrma``: schema, validator, and ``@pixiv/three-vrm-animation``
  playing it on our VRM and on the samples of other proportions.
Figures are written to /tmp/facecapges-vrm-figures.json for the record.
"""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facecapges.avatar.vrm.glb import split_glb

sys.path.insert(0, str(Path(__file__).parent))
from runtime_helpers import cli
from vrm_samples import build_sample
from vrm_schemas import VRM0, VRMC_VRM, VRMC_VRM_ANIMATION, semantic_errors

FRAMES = (120, 480, 840)  # of the BEAT take: arms in three different places
FIGURES: dict = {}
SEGMENTS = [(f"{s}UpperArm", f"{s}LowerArm", f"{S}Arm", f"{S}ForeArm") for s, S in (("left", "Left"), ("right", "Right"))] \
    + [(f"{s}LowerArm", f"{s}Hand", f"{S}ForeArm", f"{S}Hand") for s, S in (("left", "Left"), ("right", "Right"))]
FINGERS = [(f"{s}{f}Proximal", f"{s}{f}Intermediate", f"{S}Hand{g}1", f"{S}Hand{g}2")
           for s, S in (("left", "Left"), ("right", "Right")) for f, g in (("Index", "Index"), ("Middle", "Middle"))]
BONES = sorted({n for seg in SEGMENTS + FINGERS for n in seg[:2]})


def _validate(doc: dict, name: str, schema: dict) -> None:
    import jsonschema

    jsonschema.validate(doc["extensions"][name], schema, cls=jsonschema.Draft202012Validator)
    assert semantic_errors(doc, name) == []


def _khronos(path: Path) -> dict:
    from conftest import REPO

    r = subprocess.run(["node", str(REPO / "scripts" / "validate-gltf.mjs"), str(path)], capture_output=True,
                       text=True, cwd=REPO)
    return json.loads(r.stdout)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(_unit(a), _unit(b)), -1.0, 1.0))))


@pytest.fixture(scope="module")
def beat():
    from conftest import shared_file
    from facecapges.avatar.vrm.view import bvh_local_matrices
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import global_transforms

    m = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    L = bvh_local_matrices(m.skeleton, m.motion)
    _, P = global_transforms(m.skeleton, L[list(FRAMES)])
    return {"motion": m, "skel": m.skeleton, "L": L, "P": P}


@pytest.fixture(scope="module")
def files(beat, tmp_path_factory, our_vrms):
    """Our VRM 1.0 (through the CLI) and 0.x (the session's ``our_vrms``), the samples, and a 6 s .vrma of the
    BEAT take with a face."""
    from facecapges.avatar.vrm.animation import write_vrma

    d = tmp_path_factory.mktemp("vrm")
    out = dict(our_vrms)
    for v in ("vrm1", "vrm0", "glb"):
        out[v] = d / f"sample_{v}.{'glb' if v == 'glb' else 'vrm'}"
        out[v].write_bytes(build_sample(v))
    T = 900
    arkit = np.zeros((T, 52))
    arkit[:, 8] = arkit[:, 9] = np.linspace(0, 1, T)  # eyeBlinkLeft/Right ramp up
    out["vrma"] = write_vrma(d / "gestures.vrma", beat["skel"], beat["L"][:T], beat["motion"].fps, arkit, "presets")
    out["vrma_ps"] = write_vrma(d / "gestures_ps.vrma", beat["skel"], beat["L"][:T], beat["motion"].fps, arkit,
                                "perfect-sync")
    FIGURES["bytes"] = {k: p.stat().st_size for k, p in out.items()}
    yield out
    Path("/tmp/facecapges-vrm-figures.json").write_text(json.dumps(FIGURES, indent=1) + "\n")


# ------------------------------------------------------------------------------------ VRM out
def test_our_vrm_matches_the_vrm_1_0_schemas_and_the_khronos_validator(files):
    import jsonschema

    doc, _ = split_glb(files["ours"].read_bytes())
    assert doc["extensionsUsed"] == ["VRMC_vrm"]
    _validate(doc, "VRMC_vrm", VRMC_VRM)
    ext = doc["extensions"]["VRMC_vrm"]
    assert ext["meta"]["licenseUrl"] == "https://vrm.dev/licenses/1.0/" and ext["meta"]["avatarPermission"] == "everyone"
    assert len(ext["humanoid"]["humanBones"]) == 52 and ext["lookAt"]["type"] == "expression"
    # every preset but neutral, which binds nothing (the schema wants a bind: minItems 1)
    assert len(ext["expressions"]["custom"]) == 52 and len(ext["expressions"]["preset"]) == 17
    assert "neutral" not in ext["expressions"]["preset"]
    # the soles stand on y = 0 (VRM T-pose): hips about 0.9 m up, the lift on Hips itself (as VRoid's exports:
    # a VMC sender's Hips position is its height above the avatar's origin), Root at the origin
    nodes = doc["nodes"]
    root = next(n for n in nodes if n["name"] == "Root")
    hips = next(n for n in nodes if n["name"] == "Hips")
    assert root.get("translation", [0, 0, 0]) == [0, 0, 0] and 0.8 < hips["translation"][1] < 1.0
    # the schema can fail: no licence, a preset name used for a custom expression
    bad = json.loads(json.dumps(ext))
    del bad["meta"]["licenseUrl"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, VRMC_VRM, cls=jsonschema.Draft202012Validator)
    bad = json.loads(json.dumps(ext))
    bad["expressions"]["preset"]["neutral"] = {"morphTargetBinds": []}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, VRMC_VRM, cls=jsonschema.Draft202012Validator)
    bad = json.loads(json.dumps(ext))
    bad["expressions"]["custom"]["blink"] = {}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, VRMC_VRM, cls=jsonschema.Draft202012Validator)
    report = _khronos(files["ours"])
    assert report["numErrors"] == 0 and report["numWarnings"] == 0, report
    FIGURES["schema"] = {"ours.vrm": "valid", "khronos": {k: report[k] for k in ("numErrors", "numWarnings")}}
    # the samples are valid too (they are test inputs, not our writer's)
    sdoc, _ = split_glb(files["vrm1"].read_bytes())
    _validate(sdoc, "VRMC_vrm", VRMC_VRM)


def test_our_vrm0_matches_the_vrm_0_x_schema(files):
    import jsonschema

    doc, _ = split_glb(files["ours0"].read_bytes())
    assert doc["extensionsUsed"] == ["VRM"]
    ext = doc["extensions"]["VRM"]
    jsonschema.validate(ext, VRM0, cls=jsonschema.Draft202012Validator)
    groups = {g["name"]: g for g in ext["blendShapeMaster"]["blendShapeGroups"]}
    assert len(groups) == 70 and groups["Joy"]["presetName"] == "joy" and groups["EyeBlinkLeft"]["binds"]
    # the licence lets importers edit it without asking: Blender's VRM add-on (importer/license_validation.py)
    # asks for a confirmation on CC_BY_ND / CC_BY_NC_ND, on "Other" and on any other-licence or -permission URL
    meta = ext["meta"]
    assert meta["licenseName"] not in ("CC_BY_ND", "CC_BY_NC_ND", "Other", "Redistribution_Prohibited"), meta
    assert not meta.get("otherPermissionUrl") and not meta.get("otherLicenseUrl"), meta
    # BlendShape lookAt: a 30° look (ARKit eyeLook* = 1) maps to weight 1 (xRange degrees → yRange weight)
    for k in ("lookAtHorizontalInner", "lookAtHorizontalOuter", "lookAtVerticalDown", "lookAtVerticalUp"):
        assert ext["firstPerson"][k]["xRange"] == 30 and ext["firstPerson"][k]["yRange"] == 1, ext["firstPerson"][k]
    # VRM 0.x faces -Z: the left hand is at -X
    nodes = doc["nodes"]
    left = next(n for n in nodes if n["name"] == "LeftArm")
    assert left["translation"][0] < 0
    report = _khronos(files["ours0"])
    # the only warning: VRM 0.x's extension name "VRM" has no vendor prefix (every VRM 0.x has it)
    assert report["numErrors"] == 0 and [m["code"] for m in report["messages"] if m["severity"] <= 1] == [
        "INVALID_EXTENSION_NAME_FORMAT"], report
    FIGURES.setdefault("schema", {})["ours0.vrm"] = "valid"


def test_presets_we_write_map_back_to_themselves():
    """The preset clips of our VRM, read by the project's ARKit → VRM mapping, give that preset."""
    from facecapges.arkit import ARKIT_NAMES
    from facecapges.avatar.vrm.expressions import PRESET_BINDS, vrm1_expressions

    for preset, binds in PRESET_BINDS.items():
        if not binds:
            continue
        face = np.zeros(52)
        for a, w in binds.items():
            face[ARKIT_NAMES.index(a)] = w
        got = vrm1_expressions(face)
        top = max(got, key=got.get)
        assert top == preset or got[preset] > 0.9, (preset, got)


# ---------------------------------------------------------------------- three-vrm in Chromium
def _session(path: Path, beat, vrma: Path | None = None, size=(480, 360), correction: bool = True):
    from facecapges.avatar.render.browser import Browser
    from facecapges.avatar.vrm.view import VrmDriver

    driver = VrmDriver.from_file(path, beat["skel"])
    if not correction:
        driver.retarget.correction[:] = np.eye(3)
    page = driver.page()
    routes = dict(page.routes)
    if vrma is not None:
        routes["/anim.vrma"] = vrma.read_bytes()
    b = Browser(routes, page.url(*size), *size)
    b.__enter__()
    info = b.wait_for("window.facecapges.ready")
    return b, driver, info


def _arm_errors(beat, k: int, pos: dict, segments=SEGMENTS) -> dict:
    names = beat["skel"].names
    out = {}
    for a, b, A, B in segments:
        if pos.get(a) is None or pos.get(b) is None:
            continue
        want = beat["P"][k, names.index(B)] - beat["P"][k, names.index(A)]
        out[f"{a}->{b}"] = _angle(np.subtract(pos[b], pos[a]), want)
    return out


def _hand_pixels(img: np.ndarray, colour: str) -> np.ndarray:
    b, g, r = (img[..., i].astype(int) for i in range(3))
    mask = (r > 180) & (g < 80) & (b < 80) if colour == "red" else (b > 180) & (r < 80) & (g < 80)
    return np.argwhere(mask)[:, ::-1]  # (x, y)


def _screenshot_errors(b, driver, beat, k: int, quats: np.ndarray, pos: dict) -> list[float]:
    """2-D angle at the elbow between where the hand is drawn and where BEAT FK puts it."""
    import cv2

    names = beat["skel"].names
    png = base64.b64decode(b.evaluate(f"window.facecapges.renderStill({json.dumps(quats.ravel().tolist())}, null)")
                           .split(",", 1)[1])
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    rest = driver.model.rest
    errs = []
    for side, S, colour in (("left", "Left", "red"), ("right", "Right", "blue")):
        px = _hand_pixels(img, colour)
        if len(px) < 25:  # hidden behind the body in this frame
            continue
        fore = np.linalg.norm(rest[f"{side}Hand"] - rest[f"{side}LowerArm"])
        u_fore = _unit(beat["P"][k, names.index(f"{S}Hand")] - beat["P"][k, names.index(f"{S}ForeArm")])
        u_hand = _unit(beat["P"][k, names.index(f"{S}HandMiddle1")] - beat["P"][k, names.index(f"{S}Hand")])
        elbow = np.asarray(pos[f"{side}LowerArm"])
        expect = elbow + u_fore * fore + u_hand * 0.045
        e_px, x_px = b.evaluate(f"window.facecapges.project({json.dumps([elbow.tolist(), expect.tolist()])})")
        errs.append(_angle(px.mean(0) - np.asarray(e_px), np.asarray(x_px) - np.asarray(e_px)))
    return errs


@pytest.mark.parametrize("name", ["ours", "ours0", "vrm1", "vrm0", "glb"])
@pytest.mark.slow
def test_arms_point_where_beat_fk_says_and_the_vrma_plays(name, files, beat):
    b, driver, info = _session(files[name], beat, vrma=files["vrma"])
    fig = FIGURES.setdefault("avatars", {}).setdefault(name, {})
    try:
        assert b.evaluate("window.facecapges.errors") == []
        assert info["metaVersion"] == ("0" if name in ("vrm0", "ours0") else "1")
        assert info["joints"] == len(driver.retarget.bones) >= 22
        fig["three_vrm"] = {"metaVersion": info["metaVersion"], "humanBones": len(info["humanBones"]),
                            "expressions": len(info["expressionNames"])}
        L = beat["L"][list(FRAMES)]
        quats, _ = driver.frames(L, np.zeros((len(FRAMES), 52)))
        errs, shots, fingers = [], [], []
        for i in range(len(FRAMES)):
            pos = b.evaluate(f"window.facecapges.posedBones({json.dumps(quats[i].ravel().tolist())}, "
                             f"{json.dumps(BONES)})")
            errs += list(_arm_errors(beat, i, pos).values())
            fingers += list(_arm_errors(beat, i, pos, FINGERS).values())
            if not name.startswith("ours"):
                shots += _screenshot_errors(b, driver, beat, i, quats[i], pos)
        fig["arm_direction_error_deg"] = {"median": float(np.median(errs)), "max": float(np.max(errs))}
        assert max(errs) < 2.0, errs
        if name in ("ours", "ours0", "vrm1"):  # the avatars with fingers
            fig["finger_direction_error_deg"] = {"median": float(np.median(fingers)), "max": float(np.max(fingers))}
            assert len(fingers) == 12 and max(fingers) < 2.0, fingers
        if not name.startswith("ours"):
            fig["screenshot_hand_error_deg"] = {"median": float(np.median(shots)), "max": float(np.max(shots)),
                                                "hands_seen": len(shots)}
            assert len(shots) >= 3 and max(shots) < 8.0, shots
        # the rest pose is far from these poses: the check can fail
        rest = b.evaluate(f"window.facecapges.posedBones(null, {json.dumps(BONES)})")
        assert np.median(list(_arm_errors(beat, 0, rest).values())) > 20
        if name == "glb":
            return  # VRM Animation assumes a VRM T-pose rest; the A-pose GLB is not one (only our retargeting fixes it)
        # the .vrma, played by @pixiv/three-vrm-animation on this avatar
        anim = b.evaluate("window.facecapges.loadVrma('/anim.vrma')")
        assert anim["humanoidTracks"] == 52 and anim["duration"] == pytest.approx(899 / 15, abs=1e-3)
        assert b.evaluate("window.facecapges.errors") == []
        verr = []
        for i, k in enumerate(FRAMES):
            r = b.evaluate(f"window.facecapges.seekVrma({k / 15}, {json.dumps(BONES)}, ['blink'])")
            verr += list(_arm_errors(beat, i, r["bones"]).values())
            if "blink" in info["expressionNames"]:
                assert r["expressions"]["blink"] == pytest.approx(k / 899, abs=0.02)
        fig["vrma_arm_direction_error_deg"] = {"median": float(np.median(verr)), "max": float(np.max(verr)),
                                               "tracks": anim["tracks"]}
        assert max(verr) < 2.0, verr
        if name == "ours":  # the perfect-sync .vrma drives our 52 ARKit expressions
            b.routes["/anim_ps.vrma"] = files["vrma_ps"].read_bytes()
            anim = b.evaluate("window.facecapges.loadVrma('/anim_ps.vrma')")
            assert anim["expressionTracks"] == 52
            r = b.evaluate(f"window.facecapges.seekVrma({FRAMES[1] / 15}, [], ['EyeBlinkLeft', 'JawOpen'])")
            assert r["expressions"]["EyeBlinkLeft"] == pytest.approx(FRAMES[1] / 899, abs=0.02)
            assert r["expressions"]["JawOpen"] == pytest.approx(0.0, abs=1e-6)
    finally:
        b.close()


@pytest.mark.slow
def test_without_rest_pose_correction_the_a_pose_avatar_points_wrong(files, beat):
    """The negative control: the same A-pose GLB driven without the correction misses by the A-pose angle."""
    b, driver, _ = _session(files["glb"], beat, correction=False)
    try:
        quats, _ = driver.frames(beat["L"][[FRAMES[0]]], np.zeros((1, 52)))
        pos = b.evaluate(f"window.facecapges.posedBones({json.dumps(quats[0].ravel().tolist())}, {json.dumps(BONES)})")
        errs = _arm_errors(beat, 0, pos)
        FIGURES["a_pose_without_correction_deg"] = float(np.median(list(errs.values())))
        assert np.median(list(errs.values())) > 25
    finally:
        b.close()


@pytest.mark.parametrize("name", ["ours", "ours0"])
@pytest.mark.slow
def test_our_gaze_range_in_three_vrm(files, beat, name):
    """three-vrm's lookAt maps a 30° look (ARKit eyeLook* = 1) to expression weight 1 on both our VRMs."""
    b, _, _ = _session(files[name], beat, size=(160, 120))
    try:
        js = ("(() => { const a = window.facecapges.scene.vrm.lookAt.applier; return ['rangeMapHorizontalInner', "
              "'rangeMapHorizontalOuter', 'rangeMapVerticalDown', 'rangeMapVerticalUp'].map(k => [a[k].map(30), "
              "a[k].map(15)]); })()")
        for full, half in b.evaluate(js):
            assert full == pytest.approx(1.0) and half == pytest.approx(0.5)
        assert b.evaluate("window.facecapges.errors") == []
    finally:
        b.close()


@pytest.mark.slow
def test_our_vrm_expressions_drive_its_morph_targets(files, beat):
    from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES

    b, driver, info = _session(files["ours"], beat, size=(160, 120))
    try:
        assert driver.faces.perfect_sync and driver.faces.names == list(PERFECT_SYNC_NAMES)
        assert set(info["expressionNames"]) >= set(PERFECT_SYNC_NAMES) | {"aa", "blink", "happy", "lookLeft"}
        js = ("(() => { const s = window.facecapges.scene, em = s.vrm.expressionManager; em.setValue('%s', 1); "
              "s.update(); let m = null; s.vrm.scene.traverse(o => { if (o.isMesh && o.morphTargetDictionary && "
              "'%s' in o.morphTargetDictionary) m = o; }); const v = m.morphTargetInfluences["
              "m.morphTargetDictionary['%s']]; em.setValue('%s', 0); s.update(); return v; })()")
        assert b.evaluate(js % ("JawOpen", "jawOpen", "jawOpen", "JawOpen")) == pytest.approx(1.0)
        assert b.evaluate(js % ("blink", "eyeBlinkLeft", "eyeBlinkLeft", "blink")) == pytest.approx(1.0)
    finally:
        b.close()


def test_vrma_files_match_the_vrm_animation_schema(files):
    for key, group, n in (("vrma", "preset", 13), ("vrma_ps", "custom", 52)):
        doc, _ = split_glb(files[key].read_bytes())
        _validate(doc, "VRMC_vrm_animation", VRMC_VRM_ANIMATION)
        ext = doc["extensions"]["VRMC_vrm_animation"]
        assert len(ext["humanoid"]["humanBones"]) == 52 and len(ext["expressions"][group]) == n
        # rotations only, on humanoid nodes; expressions as translation X
        bone_nodes = {d["node"] for d in ext["humanoid"]["humanBones"].values()}
        for ch in doc["animations"][0]["channels"]:
            assert (ch["target"]["path"] == "rotation") == (ch["target"]["node"] in bone_nodes)
        report = _khronos(files[key])
        assert report["numErrors"] == 0 and report["numWarnings"] == 0, report
    FIGURES.setdefault("schema", {})["vrma"] = "valid"


# --------------------------------------------------------------------------------- bad files
def _cli(*args):
    return cli(*args)


def test_bad_avatars_get_one_clear_error(files, tmp_path, beat):
    from facecapges.avatar.vrm.glb import join_glb

    bvh = tmp_path / "short.bvh"
    from facecapges.io.bvh import write_bvh

    write_bvh(bvh, beat["skel"], beat["motion"].motion[:5], beat["motion"].fps)
    text = tmp_path / "notes.vrm"
    text.write_text("not a model\n")
    doc, blob = split_glb(files["vrm1"].read_bytes())
    no_hand = json.loads(json.dumps(doc))
    del no_hand["extensions"]["VRMC_vrm"]["humanoid"]["humanBones"]["leftHand"]
    (tmp_path / "nohand.vrm").write_bytes(join_glb(no_hand, blob))
    draco = json.loads(json.dumps(doc))
    draco["extensionsUsed"].append("KHR_draco_mesh_compression")
    draco["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    (tmp_path / "draco.vrm").write_bytes(join_glb(draco, blob))
    cases = (("notes.vrm", "not a VRM or binary glTF"), ("nohand.vrm", "lacks the required bones ['leftHand']"),
             ("draco.vrm", "KHR_draco_mesh_compression"))
    from facecapges.avatar.vrm.read import load_model
    from facecapges.errors import UserError

    for f, msg in cases:
        with pytest.raises(UserError, match=re.escape(msg)):
            load_model(tmp_path / f)
    # and through the command line: one line, exit status 2, nothing written
    r = _cli("render", "--bvh", str(bvh), "--avatar", str(tmp_path / "nohand.vrm"), "--out", str(tmp_path / "x.mp4"))
    assert r.returncode == 2 and cases[1][1] in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x.mp4").exists()


@pytest.mark.slow
def test_render_cli_draws_a_vrm(files, tmp_path, beat):
    import imageio_ffmpeg

    from facecapges.io.bvh import write_bvh

    bvh = tmp_path / "short.bvh"
    write_bvh(bvh, beat["skel"], beat["motion"].motion[300:312], beat["motion"].fps)
    out = tmp_path / "v0.mp4"
    r = _cli("render", "--bvh", str(bvh), "--avatar", str(files["vrm0"]), "--out", str(out), "--size", "160x120")
    assert r.returncode == 0, r.stderr
    assert "VRM 0.x" in r.stdout and "12 frames" in r.stdout
    frames = list(imageio_ffmpeg.read_frames(str(out)))[1:]
    assert len(frames) == 12
    # the same BVH as VRM Animation (avatar vrma)
    r = _cli("avatar", "vrma", "--bvh", str(bvh), "--out", str(tmp_path / "s.vrma"))
    assert r.returncode == 0, r.stderr
    doc, _ = split_glb((tmp_path / "s.vrma").read_bytes())
    _validate(doc, "VRMC_vrm_animation", VRMC_VRM_ANIMATION)
    assert doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]["count"] == 12


@pytest.mark.slow
def test_render_frames_a_big_headed_vrm_whole(tmp_path, beat):
    """``render --avatar`` with a VRM whose head is 3× ours: the camera frames the avatar's own top, nothing cropped."""
    import imageio_ffmpeg

    from facecapges.io.bvh import write_bvh

    avatar = tmp_path / "bighead.vrm"
    avatar.write_bytes(build_sample("vrm0", head_scale=3.0))
    bvh = tmp_path / "short.bvh"
    write_bvh(bvh, beat["skel"], beat["motion"].motion[300:302], beat["motion"].fps)
    out = tmp_path / "big.mp4"
    r = _cli("render", "--bvh", str(bvh), "--avatar", str(avatar), "--out", str(out), "--size", "320x240")
    assert r.returncode == 0, r.stderr
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    w, h = meta["size"]
    img = np.frombuffer(next(reader), np.uint8).reshape(h, w, 3).astype(int)
    import cv2

    cv2.imwrite("/tmp/facecapges-vrm-bighead.png", img[..., ::-1].astype(np.uint8))
    body = img[:, : int(w * 0.6)]  # left of the face inset (top right)
    bg = body[0, 0]
    rows = np.where((np.abs(body - bg).sum(-1) > 60).any(1))[0]
    assert len(rows) and rows[0] > 3, rows[:5]  # the top of the head is inside the frame, below a margin
    assert rows[0] < 0.25 * h  # … and near the top, not a tiny figure
    FIGURES["big_head_top_row_px"] = int(rows[0])


@pytest.mark.slow
def test_vrm_bench_runs():
    from conftest import SHARED
    from facecapges.benchmarks.vrm import run

    r = run(quick=True, shared=SHARED)
    assert r["bones"] == 52 and r["vrma_900_bytes"] > 100_000
    assert all(r[k] > 0 for k in ("retarget_frame_ms", "presets_frame_ms", "retarget_900_ms", "vrma_900_s"))
    FIGURES["bench"] = r


def test_our_vrm_files_state_one_licence(files):
    """VRM 1.0 and 0.x say the same licence, CC BY 4.0: 0.x by name, 1.0 in its copyright field with the VRM
    Public License's parameters set to CC BY's terms (credit required) — not "MIT" beside the VRM licence."""
    doc1, _ = split_glb(files["ours"].read_bytes())
    doc0, _ = split_glb(files["ours0"].read_bytes())
    m1, m0 = doc1["extensions"]["VRMC_vrm"]["meta"], doc0["extensions"]["VRM"]["meta"]
    assert m0["licenseName"] == "CC_BY"
    assert "CC BY 4.0" in m1["copyrightInformation"] and "MIT" not in json.dumps(m1) + json.dumps(m0)
    assert m1["creditNotation"] == "required" and m1["allowRedistribution"] and m1["commercialUsage"] == "corporation"
    assert m1["modification"] == "allowModificationRedistribution"
