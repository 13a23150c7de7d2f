"""Issue 34, items 3-7: files from outside that were trusted. Each case was a traceback, a silent exit 0
with damaged output, or gigabytes of memory on main; here it is one ``error:`` line (exit 2) or a
warning, and nothing the user had is lost.

3. BEAT2 ``.npz`` archives: sizes are checked on the zip member and the npy header before anything is
   unpacked (a 392 KB archive of deflated zeros declaring 300000 x 165 poses, a header declaring 10^12
   frames), rotations beyond a few pi and non-finite values are refused, the real reason is said, and
   takes too short to use are warned about.
4. Crafted matching styles: every array's length and width against the database, every type and
   range of the metadata; ``styles list`` marks a broken style and lists the others.
5. Speech that does not match its motion: a warning above a few frames, refused beyond 10 %.
6. A 300-character style name. 7. ``styles install`` over a symlinked ``NAME.fgd``.
"""

from __future__ import annotations

import io
import json
import math
import zipfile

import numpy as np
import pytest
import soundfile as sf

from conftest import shared_file
from facecapges.data import beat2
from facecapges.errors import UserError
from runtime_helpers import cli

NPZ_11 = "data/beat2/2_scott_0_1_1.npz"
BVH_11 = "data/beat/2_scott_0_1_1.bvh"
WAV_11 = "data/beat/2_scott_0_1_1.wav"


def _one_error_line(r, *words: str) -> None:
    """Exit 2, no traceback, one ``error:`` line holding every word."""
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    lines = [x for x in r.stderr.splitlines() if x.startswith("error:")]
    assert len(lines) == 1, r.stderr[-3000:]
    for w in words:
        assert w in lines[0], lines[0]


# ------------------------------------------------------------------ 3. BEAT2 archives
def _savez(path, compressed=False, **arrays):
    (np.savez_compressed if compressed else np.savez)(path, **arrays)
    return path


def _npy_bytes(header_shape: tuple, data: np.ndarray) -> bytes:
    """An npy member whose header declares ``header_shape`` but holds ``data``'s bytes."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": np.lib.format.dtype_to_descr(data.dtype), "fortran_order": False, "shape": header_shape}
    )
    return buf.getvalue() + data.tobytes()


def _zip(path, members: dict[str, bytes], compress=zipfile.ZIP_DEFLATED):
    with zipfile.ZipFile(path, "w", compress) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def _fps_member(fps=30) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.array(fps))
    return buf.getvalue()


def _beat2_layout(root, name: str, npz_maker, wav_seconds: float | None = None):
    """A BEAT2 folder (smplxflame_30/NAME.npz, wave16k/NAME.wav) with the take made by ``npz_maker(path)``."""
    (root / "smplxflame_30").mkdir(parents=True)
    (root / "wave16k").mkdir()
    npz_maker(root / "smplxflame_30" / f"{name}.npz")
    audio, sr = sf.read(shared_file(WAV_11), dtype="float32")
    if wav_seconds is not None:
        audio = audio[: int(wav_seconds * sr)]
    sf.write(root / "wave16k" / f"{name}.wav", audio, sr)
    return root


def _real_poses() -> np.ndarray:
    with np.load(shared_file(NPZ_11)) as z:
        return np.asarray(z["poses"])


def _zeros_bomb(p):
    """392 KB on disk, 396 MB of poses unpacked: 10,000 s at 30 fps."""
    _savez(p, compressed=True, poses=np.zeros((300_000, 165)), mocap_frame_rate=np.array(30))


def _frames_over_cap(p):
    """53 MB of poses (under the member cap), 80,000 frames: past the 20-minute cap."""
    _savez(p, compressed=True, poses=np.zeros((80_000, 165), np.float32), mocap_frame_rate=np.array(30))


def _header_giant(p):
    _zip(p, {"poses.npy": _npy_bytes((10**12, 165), np.zeros((2, 165))), "mocap_frame_rate.npy": _fps_member()})


def _huge_values(p):
    poses = _real_poses().astype(np.float64)
    poses[100:110, 60:63] = 1e300
    _savez(p, poses=poses, mocap_frame_rate=np.array(30))


def _truncated_member(p):
    """A header declaring 1906 frames over 10 frames of data: damaged, not 'Python objects'."""
    _zip(p, {"poses.npy": _npy_bytes((1906, 165), np.zeros((10, 165))), "mocap_frame_rate.npy": _fps_member()})


def _member_too_big(p):
    """A member whose uncompressed size alone is past the cap (a 'trans' of 10 million rows of zeros)."""
    _savez(p, compressed=True, poses=_real_poses(), mocap_frame_rate=np.array(30), trans=np.zeros((5 * 10**6, 3)))


@pytest.mark.parametrize(
    "maker, words",
    [
        (_zeros_bomb, ("'poses' unpacks to 378 MB, more than the 96 MB",)),
        (_frames_over_cap, ("80000 frames at 30 fps (44.4 min): longer than a BEAT2 take may be",)),
        (_header_giant, ("1000000000000 frames",)),
        (_huge_values, ("beyond 4π", "frame 100")),
        (_truncated_member, ("damaged", "declares shape (1906, 165)")),
        (_member_too_big, ("'trans' unpacks to 114 MB",)),
    ],
    ids=["deflated-zeros", "frames-over-cap", "header-1e12-frames", "poses-1e300", "truncated", "member-over-cap"],
)
def test_a_crafted_beat2_take_is_refused_before_it_costs_memory(tmp_path, maker, words):
    import tracemalloc

    p = maker(tmp_path / "2_scott_0_1_1.npz") or tmp_path / "2_scott_0_1_1.npz"
    tracemalloc.start()
    try:
        with pytest.raises(UserError) as exc:
            beat2.read_beat2(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(exc.value)
    assert "Python objects" not in msg and all(w in msg for w in words), msg
    assert peak < 64 << 20, f"{peak / 2**20:.0f} MB allocated to refuse it"  # main: 396 MB and more


def test_prepare_refuses_a_crafted_take_with_one_line(tmp_path):
    target = shared_file(BVH_11)
    for maker in (_zeros_bomb, _huge_values, _header_giant):
        root = _beat2_layout(tmp_path / maker.__name__, "2_scott_0_1_1", maker)
        out = tmp_path / f"cache-{maker.__name__}"
        r = cli("prepare", str(root), "--out", str(out), "--target", str(target), "--quiet", timeout=300)
        _one_error_line(r, "2_scott_0_1_1.npz")
        assert not out.exists()  # no cache of NaN poses, nothing half-written


def test_prepare_warns_on_a_take_too_short_to_use(tmp_path):
    from facecapges.data.prepare import prepare
    from facecapges.io.bvh import read_bvh
    from facecapges.matching.build import MIN_TRAIN_S

    assert beat2.MIN_USEFUL_S == MIN_TRAIN_S / 0.8  # what `styles build` needs
    root = _beat2_layout(
        tmp_path / "b", "2_scott_0_1_1", lambda p: _savez(p, poses=_real_poses()[:150], mocap_frame_rate=np.array(30)),
        wav_seconds=5.0,
    )
    index = prepare(root, tmp_path / "cache", progress=False, target=read_bvh(shared_file(BVH_11)).skeleton)
    assert [c["n_frames"] for c in index["clips"]] == [75]
    assert any("too short to use" in w and "5.0 s" in w for w in index["warnings"]), index["warnings"]


def test_the_real_takes_still_read():
    take = beat2.read_beat2(shared_file(NPZ_11))
    assert take.poses.shape == (1906, 55, 3) and take.fps == 30.0


# ------------------------------------------------------------------ 5. speech against motion
RATE_WORDS = {  # 1906 frames declared at 1 fps: 31.8 min, past the length cap; at 1000 fps 1.9 s against 64 s of speech
    1: ("2_scott_0_1_1.npz", "1906 frames at 1 fps (31.8 min)"),
    1000: ("2_scott_0_1_1.wav", "the speech lasts 64.1 s and the motion 1.9 s", "more than 10% apart"),
}


@pytest.mark.parametrize("fps", [1, 1000])
def test_prepare_refuses_a_take_declaring_a_wrong_frame_rate(tmp_path, fps):
    root = _beat2_layout(
        tmp_path / "b", "2_scott_0_1_1", lambda p: _savez(p, poses=_real_poses(), mocap_frame_rate=np.array(fps))
    )
    out = tmp_path / "cache"
    r = cli("prepare", str(root), "--out", str(out), "--target", str(shared_file(BVH_11)), "--quiet", timeout=300)
    _one_error_line(r, *RATE_WORDS[fps])
    assert not out.exists()


def test_styles_build_refuses_speech_far_shorter_than_its_motion(tmp_path):
    wav = tmp_path / "five.wav"
    audio, sr = sf.read(shared_file(WAV_11), dtype="float32")
    sf.write(wav, audio[: 5 * sr], sr)
    out = tmp_path / "s.safetensors"
    r = cli("styles", "build", "short", "--take", str(shared_file(BVH_11)), str(wav), "--out", str(out),
            "--steps", "1", timeout=300)
    _one_error_line(r, "five.wav", "the speech lasts 5.0 s and the motion 63.8 s", "58.8 s of silence")
    assert not out.exists()


@pytest.mark.parametrize("fps", [1, 1000])
def test_styles_build_refuses_a_beat2_take_declaring_a_wrong_frame_rate(tmp_path, fps):
    npz = _savez(tmp_path / "2_scott_0_1_1.npz", poses=_real_poses(), mocap_frame_rate=np.array(fps))
    out = tmp_path / "s.safetensors"
    r = cli("styles", "build", "rate", "--take", str(npz), str(shared_file(WAV_11)), "--out", str(out),
            "--steps", "1", timeout=300)
    _one_error_line(r, *RATE_WORDS[fps])
    assert not out.exists()


def test_a_few_frames_off_is_a_warning(tmp_path):
    """BEAT2's 0_2_2: 60.1 s of motion, 62.0 s of speech (the end is cut): read, with a warning said."""
    from facecapges.matching.build import read_takes
    from facecapges.matching.takes import speech_notes
    from facecapges.styles import load_skeleton

    said: list[str] = []
    takes = read_takes([(shared_file("data/beat2/2_scott_0_2_2.npz"), shared_file("data/beat/2_scott_0_2_2.wav"))],
                       say=said.append, fallback_skeleton=load_skeleton)
    assert takes[0].n_frames == 902
    assert any("warning: 2_scott_0_2_2.wav: the speech lasts 62.0 s and the motion 60.1 s (its end is cut)" in s
               for s in said), said
    pose_frames = 957  # BEAT's BVH of 0_1_1: 63.8 s against 64.1 s of speech, 4.5 frames: no word
    assert speech_notes(shared_file(BVH_11), shared_file(WAV_11), pose_frames, np.zeros(int(64.097 * 16000))) == ()


# ------------------------------------------------------------------ 6, 7. names and the styles folder
def test_a_300_character_style_name_is_refused(tmp_path):
    r = cli("styles", "build", "a" * 300, "--take", str(shared_file(BVH_11)), str(shared_file(WAV_11)),
            timeout=120, env={"FACECAPGES_STYLES": str(tmp_path / "store")})
    _one_error_line(r, "300 characters", "at most 64")
    assert not (tmp_path / "store").exists()
    out = tmp_path / ("c" * 300 + ".safetensors")  # --out's name too: an OSError traceback on main
    r = cli("styles", "build", "short-name", "--take", str(shared_file(BVH_11)), str(shared_file(WAV_11)),
            "--out", str(out), timeout=120)
    _one_error_line(r, "at most 200 bytes")
    from facecapges.styles import install_style, styles_dir

    with pytest.raises(UserError, match="at most 64"):
        install_style(styles_dir() / "beat2-scott-mm.safetensors", name="b" * 300)


@pytest.fixture()
def run_with_fgd(tmp_path):
    from facecapges.styles import styles_dir

    run = tmp_path / "my-run"
    (run / "model.fgd").mkdir(parents=True)
    (run / "model.safetensors").write_bytes((styles_dir() / "beat2-scott-mm.safetensors").read_bytes())
    (run / "model.fgd" / "fgd.json").write_text('{"new": true}')
    return run


def test_install_over_a_symlinked_fgd_folder(tmp_path, run_with_fgd):
    store = tmp_path / "store"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(parents=True)
    (elsewhere / "keep.txt").write_text("the user's")
    store.mkdir()
    (store / "my-run.fgd").symlink_to(elsewhere)
    env = {"FACECAPGES_STYLES": str(store)}
    r = cli("styles", "install", str(run_with_fgd), timeout=120, env=env)
    _one_error_line(r, "my-run.fgd", "symbolic link", "--force")
    assert sorted(p.name for p in store.iterdir()) == ["my-run.fgd"] and (store / "my-run.fgd").is_symlink()
    r = cli("styles", "install", str(run_with_fgd), "--force", timeout=120, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    fgd = store / "my-run.fgd"
    assert fgd.is_dir() and not fgd.is_symlink() and json.loads((fgd / "fgd.json").read_text()) == {"new": True}
    assert (elsewhere / "keep.txt").read_text() == "the user's"  # the link went, not what it pointed to


# ------------------------------------------------------------------ 4. crafted matching styles
def _style_parts():
    from safetensors import safe_open

    from facecapges.styles import styles_dir

    with safe_open(str(styles_dir() / "beat2-scott-mm.safetensors"), framework="pt") as f:
        return json.loads(f.metadata()["facecapges"]), {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118


def _edit_config(**kw):
    return lambda m, t: m["engine_config"].update(kw)


def _set(key, value):
    return lambda m, t: m.__setitem__(key, value)


def _tensor(key, fn):
    return lambda m, t: t.__setitem__(key, fn(t[key]))


CRAFTED = {
    "pose-shorter": (_tensor("db.pose", lambda v: v[:-100].clone()), "db.pose"),
    "features-narrower": (_tensor("db.features", lambda v: v[:, :20].clone()), "db.features"),
    "mean-narrower": (_tensor("db.mean", lambda v: v[:10].clone()), "db.mean"),
    "scale-2d": (_tensor("db.scale", lambda v: v[None].clone()), "db.scale"),
    "segment-out-of-range": (_tensor("db.segment", lambda v: v + 7), "db.segment"),
    "phase-out-of-range": (_tensor("db.phase", lambda v: v + 9), "db.phase"),
    "nothing-searchable": (_tensor("db.searchable", lambda v: v * 0), "searchable"),
    "fps-string": (_set("fps", "fifteen"), "fps"),
    "fps-string-number": (_set("fps", "15"), "fps"),
    "engine-config-list": (_set("engine_config", [1, 2]), "engine_config"),
    "engine-config-string-value": (_edit_config(search_interval="2"), "search_interval"),
    "predictor-number": (_set("predictor", 5), "predictor"),
    "predictor-list": (_set("predictor", ["x"]), "predictor"),
    "predictor-settings-wrong": (lambda m, t: m["predictor"].__setitem__("settings", "x"), "predictor"),
    "segments-not-a-list": (lambda m, t: m["database"].__setitem__("segments", {"a": 1}), "database"),
    "weights-nan": (lambda m, t: m["database"]["weights"].__setitem__("speaking", math.nan), "weights"),
    "search-interval-0": (_edit_config(search_interval=0), "search_interval"),
    "halflife-negative": (_edit_config(halflife_s=-1.0), "halflife_s"),
    "margin-nan": (_edit_config(margin=math.nan), "margin"),
    "near-frames-float": (_edit_config(near_frames=2.5), "near_frames"),
    "use-predictor-string": (_edit_config(use_predictor="no"), "use_predictor"),
}


def _crafted(tmp_path, case: str):
    from safetensors.torch import save_file

    meta, tensors = _style_parts()
    CRAFTED[case][0](meta, tensors)
    p = tmp_path / f"{case}.safetensors"
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(p), metadata={"facecapges": json.dumps(meta)})
    return p


@pytest.mark.parametrize("case", sorted(CRAFTED))
def test_a_crafted_matching_style_is_refused_by_its_check(tmp_path, case):
    from facecapges.styles import load_style

    p = _crafted(tmp_path, case)
    with pytest.raises(UserError) as exc:
        load_style(p)
    assert str(p) in str(exc.value) and CRAFTED[case][1] in str(exc.value), str(exc.value)


@pytest.fixture(scope="module")
def short_wav(tmp_path_factory):
    p = tmp_path_factory.mktemp("wav") / "three.wav"
    audio, sr = sf.read(shared_file("data/beat/2_scott_0_4_4.wav"), dtype="float32")
    sf.write(p, audio[: 3 * sr], sr)
    return p


@pytest.mark.parametrize("case", ["pose-shorter", "features-narrower", "fps-string", "engine-config-list",
                                  "predictor-number", "search-interval-0", "margin-nan"])
def test_generate_with_a_crafted_style_is_one_error_line(tmp_path, short_wav, case):
    p = _crafted(tmp_path, case)
    out = tmp_path / "out.bvh"
    r = cli("generate", "--audio", str(short_wav), "--out", str(out), "--checkpoint", str(p), timeout=300)
    _one_error_line(r, p.name, CRAFTED[case][1])
    assert not out.exists()


def test_styles_list_marks_a_broken_style_and_lists_the_rest(tmp_path):
    store = tmp_path / "store"
    store.mkdir()
    for case in ("fps-string", "engine-config-list", "pose-shorter"):
        _crafted(store, case)
    r = cli("styles", "list", timeout=300, env={"FACECAPGES_STYLES": str(store)})
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    assert any("beat2-scott-mm" in x and "matching" in x for x in lines), r.stdout
    for case in ("fps-string", "engine-config-list", "pose-shorter"):
        row = [x for x in lines if case in x]
        assert len(row) == 1 and "broken" in row[0] and CRAFTED[case][1] in row[0], r.stdout
    r = cli("styles", "list", "--json", timeout=300, env={"FACECAPGES_STYLES": str(store)})
    rows = {x["name"]: x for x in json.loads(r.stdout)}
    assert rows["pose-shorter"]["engine"] is None and "db.pose" in rows["pose-shorter"]["error"]
    assert rows["beat2-scott-mm"]["error"] is None


# ------------------------------------------------------------------ 8. avatars the browser cannot load
def _vrm1_edited(fn) -> bytes:
    from facecapges.avatar.vrm.glb import join_glb, split_glb
    from vrm_samples import build_sample

    doc, binary = split_glb(build_sample("vrm1"))
    fn(doc)
    return join_glb(doc, binary)


def _chain_under_head(n: int):
    def fn(doc):
        base = len(doc["nodes"])
        head = doc["extensions"]["VRMC_vrm"]["humanoid"]["humanBones"]["head"]["node"]
        doc["nodes"][head].setdefault("children", []).append(base)
        for i in range(n):
            doc["nodes"].append({"name": f"c{i}", **({"children": [base + i + 1]} if i < n - 1 else {})})
    return fn


AVATARS = {  # what three.js / three-vrm refuse after Chromium has started → what our check says first
    "chain-5000": (_chain_under_head(5000), "nest more than 1000 levels deep"),
    "no-licence-url": (lambda d: d["extensions"]["VRMC_vrm"]["meta"].pop("licenseUrl"), "licenseUrl"),
    "other-licence-url": (
        lambda d: d["extensions"]["VRMC_vrm"]["meta"].__setitem__("licenseUrl", "https://example.org/mine"),
        "https://vrm.dev/licenses/1.0/",
    ),
    "vrmc-not-used": (lambda d: d["extensionsUsed"].remove("VRMC_vrm"), "extensionsUsed"),
}


@pytest.mark.parametrize("case", sorted(AVATARS))
def test_an_avatar_three_vrm_refuses_is_refused_before_the_browser(tmp_path, case):
    from facecapges.avatar.vrm.read import load_model

    p = tmp_path / f"{case}.vrm"
    p.write_bytes(_vrm1_edited(AVATARS[case][0]))
    with pytest.raises(UserError, match="invalid glTF") as exc:
        load_model(p)
    assert AVATARS[case][1] in str(exc.value)
    out = tmp_path / "out.mp4"
    r = cli("render", "--bvh", str(shared_file(BVH_11)), "--avatar", str(p), "--out", str(out), timeout=300)
    _one_error_line(r, p.name, AVATARS[case][1])
    assert "the browser could not" not in r.stderr and not out.exists()  # refused by the check: no Chromium


def test_the_three_vrm_requirement_is_the_installed_one():
    """The licence URL our check demands is the one @pixiv/three-vrm-core (node_modules) accepts by default."""
    from pathlib import Path

    from facecapges.avatar.vrm.meta import LICENSE_URL

    js = Path(__file__).resolve().parents[1] / "node_modules" / "@pixiv" / "three-vrm-core" / "lib"
    source = (js / "three-vrm-core.module.js").read_text(encoding="utf-8")
    assert f'options.acceptLicenseUrls) != null ? _b : ["{LICENSE_URL}"]' in source
    assert "The license url" in source and '"VRMC_vrm"' in source


def test_a_page_error_is_shown_by_its_first_line():
    """What Chromium reported for the 2,150-node chain (its stack cut): only the first line reaches the user."""
    from facecapges.avatar.render.video import _first_line

    stack = ("page error: RangeError: Maximum call stack size exceeded\n"
             "    at GLTFParser._loadNodeShallow (http://127.0.0.1:44489/three/examples/jsm/loaders/GLTFLoader.js:4420:18)\n"
             "    at GLTFParser.loadNode (http://127.0.0.1:44489/three/examples/jsm/loaders/GLTFLoader.js:4343:10)")
    assert _first_line(stack) == "page error: RangeError: Maximum call stack size exceeded"
    assert _first_line(["Error: VRMMetaLoaderPlugin: The license url \"undefined\" is not accepted\n    at x"]) == (
        'Error: VRMMetaLoaderPlugin: The license url "undefined" is not accepted')
