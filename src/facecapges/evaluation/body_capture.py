"""How well ``capture-body`` recovers known motion: arm directions and wrist spread.

Both motions (the truth BVH the avatar was rendered with, and what capture-body
recovered from the video) go through the same forward kinematics on the same
skeleton. Each arm's bone directions — shoulder→elbow (``Arm``→``ForeArm``) and
elbow→wrist (``ForeArm``→``Hand``) — are expressed in the body's frame (the global
rotation of ``Spine3``), so a lean or turn of the whole body is not counted as an
arm error. The angle between true and recovered direction is pooled over both
arms, both bones and all frames (median, 90th percentile, degrees). The wrist
spread ratio is :func:`facecapges.evaluation.synchrony.wrist_spread` of the
recovered wrists (in the body frame) over the truth's. ``frame="camera"`` compares the
directions in the world (camera) frame instead: the torso's lean, which a frontal camera
barely sees, is then not counted.

:func:`measure` is the whole proof on a take whose truth we know: the held-out last 20 %
of a BEAT BVH or a BEAT2 npz rendered on the avatar (``facecapges render``), ``capture-body``
on that video, :func:`compare`. ``python -m facecapges.evaluation.body_capture TAKE …``
prints it (docs/capture-body.md).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facecapges.evaluation.synchrony import wrist_spread
from facecapges.skeleton import Skeleton, global_transforms, local_matrices, motion_to_euler

BONES = (("Arm", "ForeArm"), ("ForeArm", "Hand"))
SIDES = ("Right", "Left")


def _body_frame_points(skel: Skeleton, motion: np.ndarray, frame: str = "body") -> tuple[np.ndarray, np.ndarray]:
    _, euler = motion_to_euler(skel, motion)
    G, P = global_transforms(skel, local_matrices(skel, euler))
    body = G[:, skel.index("Spine3")]  # (T, 3, 3)
    if frame == "camera":
        body = np.broadcast_to(np.eye(3), body.shape)
    local = np.einsum("tji,tkj->tki", body, P - P[:, skel.index("Spine3")][:, None])  # body.T @ p
    return local, body


def arm_direction_errors(skel: Skeleton, truth: np.ndarray, captured: np.ndarray, frame: str = "body") -> np.ndarray:
    """Angles (degrees) between true and recovered arm bone directions, (T, 4): R upper, R fore, L upper, L fore."""
    n = min(len(truth), len(captured))
    pt, _ = _body_frame_points(skel, truth[:n], frame)
    pc, _ = _body_frame_points(skel, captured[:n], frame)
    out = []
    for side in SIDES:
        for a, b in BONES:
            ia, ib = skel.index(f"{side}{a}"), skel.index(f"{side}{b}")
            dt, dc = pt[:, ib] - pt[:, ia], pc[:, ib] - pc[:, ia]
            cos = (dt * dc).sum(-1) / np.maximum(np.linalg.norm(dt, axis=-1) * np.linalg.norm(dc, axis=-1), 1e-9)
            out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def compare(skel: Skeleton, truth: np.ndarray, captured: np.ndarray, frame: str = "body") -> dict:
    """Median / p90 arm-direction angle (degrees), per bone medians and the wrist spread ratio."""
    err = arm_direction_errors(skel, truth, captured, frame)
    n = len(err)
    pt, _ = _body_frame_points(skel, truth[:n])
    pc, _ = _body_frame_points(skel, captured[:n])
    wr = [skel.index(f"{s}Hand") for s in SIDES]
    spread = wrist_spread(pc[:, wr]) / wrist_spread(pt[:, wr])
    names = [f"{s} {'upper arm' if a == 'Arm' else 'forearm'}" for s in SIDES for a, _ in BONES]
    return {
        "frames": int(n),
        "median_deg": float(np.median(err)),
        "p90_deg": float(np.percentile(err, 90)),
        "per_bone_median_deg": {k: float(np.median(err[:, i])) for i, k in enumerate(names)},
        "wrist_spread_ratio": float(spread),
    }


HELD_OUT = 0.2  # the last 20 % of every paired take is held out of every choice


def held_out_truth(take: str | Path, skeleton_bvh: str | Path, share: float = HELD_OUT) -> tuple[Skeleton, np.ndarray]:
    """The last ``share`` of a BEAT BVH or a BEAT2 npz (converted onto ``skeleton_bvh``'s skeleton), 15 fps motion."""
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import pose_to_motion
    from facecapges.timing import MODEL_FPS

    take = Path(take)
    if take.suffix.lower() == ".npz":
        from facecapges.data.beat2 import load_beat2_take

        skel = read_bvh(skeleton_bvh).skeleton
        motion = pose_to_motion(skel, load_beat2_take(take, fps=MODEL_FPS)[0])
    else:
        b = read_bvh(take)
        if abs(b.fps - MODEL_FPS) > 1e-6:
            raise ValueError(f"{take}: {b.fps} fps, expected {MODEL_FPS}")
        skel, motion = b.skeleton, b.motion
    return skel, motion[int(round(len(motion) * (1.0 - share))) :]


def render_truth(
    take: str | Path, work: str | Path, skeleton_bvh: str | Path | None = None, wav: str | Path | None = None
) -> tuple[Skeleton, np.ndarray, Path, Path | None]:
    """The held-out end of ``take`` rendered on the avatar (``facecapges render``) into ``work``: the skeleton,
    the truth motion (15 fps), truth.mp4 and, with the take's speech ``wav``, its held-out part (truth.wav,
    muxed into the video too)."""
    import subprocess
    import sys

    from facecapges.io.bvh import write_bvh
    from facecapges.timing import MODEL_FPS

    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    skel, truth = held_out_truth(take, skeleton_bvh or take)
    bvh, video = work / "truth.bvh", work / "truth.mp4"
    write_bvh(bvh, skel, truth, float(MODEL_FPS))
    cmd = [sys.executable, "-m", "facecapges", "render", "--bvh", str(bvh), "--out", str(video), "--force"]
    speech = None
    if wav is not None:
        from facecapges.io.audio import load_audio, save_audio
        from facecapges.timing import AUDIO_SR

        n_full = len(held_out_truth(take, skeleton_bvh or take, share=1.0)[1])
        first = n_full - len(truth)  # the held-out end's first frame
        a = load_audio(wav)
        start = int(round(first / MODEL_FPS * AUDIO_SR))
        # one frame longer than the motion (silence where the take's speech ends): the render's -shortest ends the
        # video with the audio's last AAC frame, which dropped the motion's last frame (190 of 191)
        n = int(round((len(truth) + 1) / MODEL_FPS * AUDIO_SR))
        part = a[start : start + n]
        speech = save_audio(work / "truth.wav", np.pad(part, (0, n - len(part))))
        cmd += ["--audio", str(speech)]
    cache = os.environ.get(RENDER_CACHE_ENV)
    key = _render_key([bvh] + ([speech] if speech else []), cmd[3:]) if cache else ""
    with _cache_lock(cache, key):
        if cache and (Path(cache) / f"{key}.mp4").is_file():
            shutil.copyfile(Path(cache) / f"{key}.mp4", video)
            return skel, truth, video, speech
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"render failed: {r.stderr.strip()[-500:]}")
        if cache:  # copied under another name, then renamed: a reader never sees half a file
            shutil.copyfile(video, Path(cache) / f"{key}.part")
            os.replace(Path(cache) / f"{key}.part", Path(cache) / f"{key}.mp4")
    return skel, truth, video, speech


RENDER_CACHE_ENV = "FACECAPGES_RENDER_CACHE"  # set by the test suite only (tests/conftest.py, docs/testing.md)


def _render_key(inputs: list[Path], args: list[str]) -> str:
    """What decides :func:`render_truth`'s pixels and sound: the input files' bytes (the truth BVH — its motion,
    frame range and fps — and the speech), the render options but the paths, and the renderer: every file of
    the installed package (code, web page, avatar assets) and three.js's version."""
    import hashlib

    from facecapges.avatar.blendshapes import package_digest
    from facecapges.avatar.render.browser import three_dir

    h = hashlib.sha256()
    for f in inputs:
        h.update(f.read_bytes())
    h.update(repr([a for a in args if not a.endswith((".bvh", ".mp4", ".wav"))]).encode())
    package_digest(h)
    h.update((three_dir() / "package.json").read_bytes())
    return h.hexdigest()[:32]


@contextlib.contextmanager
def _cache_lock(cache: str | None, key: str) -> Iterator[None]:
    """Held while one process renders ``key`` into ``cache``: the others (xdist workers, the bench's
    subprocess) wait, then copy its file."""
    if not cache:
        yield
        return
    from filelock import FileLock

    Path(cache).mkdir(parents=True, exist_ok=True)
    with FileLock(str(Path(cache) / f"{key}.lock")):
        yield


def measure(
    take: str | Path, work: str | Path, skeleton_bvh: str | Path | None = None, wav: str | Path | None = None
) -> dict:
    """Render the held-out end of ``take`` on the avatar (with its speech ``wav``: the mouth moves, as in
    :func:`~facecapges.evaluation.live_body.measure_live`'s video), capture-body it back, compare with the truth.

    ``work``: a folder for truth.bvh, truth.mp4 and captured.bvh. Returns :func:`compare`'s figures in the
    body frame, ``camera`` (the same in the camera frame) and the capture's summary (hands found …)."""
    from facecapges.capture.body import capture_body
    from facecapges.skeleton import pose_to_motion

    work = Path(work)
    skel, truth, video, _ = render_truth(take, work, skeleton_bvh, wav)
    res, summary = capture_body(video, work / "captured.bvh", skel)
    captured = pose_to_motion(skel, res.pose)
    out = compare(skel, truth, captured)
    out["camera"] = compare(skel, truth, captured, frame="camera")
    out["capture"] = {k: summary[k] for k in ("pose_found", "hands_found", "both_hands_found", "ms_per_frame")}
    return out


def main(argv: list[str] | None = None) -> None:
    import argparse
    import json
    import tempfile

    ap = argparse.ArgumentParser(description="capture-body against the truth on the held-out end of known takes")
    ap.add_argument("takes", nargs="+", help="BEAT BVH or BEAT2 npz takes")
    ap.add_argument("--skeleton", help="a BEAT BVH whose skeleton a BEAT2 take is put on")
    args = ap.parse_args(argv)
    for take in args.takes:
        with tempfile.TemporaryDirectory() as tmp:
            m = measure(take, tmp, args.skeleton)
        print(json.dumps({"take": Path(take).name, **m}, indent=1))


if __name__ == "__main__":
    main()
