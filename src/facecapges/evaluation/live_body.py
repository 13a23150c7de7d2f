"""How ``live --body`` follows known motion, and how its hand-overs move (issue 32).

The proof of :mod:`facecapges.evaluation.body_capture`, on the live path: the held-out end of a take
rendered on the avatar with his speech (:func:`~facecapges.evaluation.body_capture.render_truth`) is fed
to ``facecapges live --video truth.mp4 --audio truth.wav --body --record DIR`` (a subprocess: the
command itself), and the recorded motion is compared with the truth by the same arm-direction measure
(:func:`~facecapges.evaluation.body_capture.compare`: median / p90 angle, wrist spread).

:func:`leave_frame` makes the hand-over happen on the same video: over :data:`LEAVE_SPANS` the picture
is shifted so that the subject's right arm leaves the frame at the image's left edge, then both hands
leave at the bottom (the head stays in view), and back. At each hand-over the output's whole-body
joint acceleration (:func:`facecapges.evaluation.realism.joint_acceleration`) is compared with the pop
rule of the conversation metric (:mod:`facecapges.evaluation.conversation`): above the 99.9th percentile
of his real motion (his training frames, the take's first 80 %) is a pop.

``python -m facecapges.evaluation.live_body TAKE WAV`` prints both runs (docs/capture-body.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from facecapges.evaluation import realism as rz
from facecapges.evaluation.body_capture import HELD_OUT, compare, held_out_truth, render_truth
from facecapges.skeleton import Skeleton, motion_to_pose, pose_to_motion
from facecapges.timing import MODEL_FPS

# (start s, end s, how): "left" shifts the picture left (the subject's right arm leaves), "down" shifts it down
LEAVE_SPANS: tuple[tuple[float, float, str], ...] = ((3.0, 6.0, "left"), (8.0, 11.0, "down"))
SHIFT = {"left": (-0.3, 0.0), "down": (0.0, 0.5)}  # share of the width / height
NEAR_HANDOVER = (-1, 8)  # frames around a hand-over whose acceleration is checked (the blend's first 0.5 s)


def leave_frame(video: str | Path, out: str | Path, spans=LEAVE_SPANS) -> Path:
    """``video`` with the picture shifted over ``spans`` (module docstring), H.264 without sound."""
    import cv2
    import imageio_ffmpeg

    from facecapges.capture.video import open_source

    src = open_source(str(video))
    w, h, fps = src.width, src.height, src.fps
    writer = imageio_ffmpeg.write_frames(str(out), (w, h), fps=fps, codec="libx264", quality=8, macro_block_size=1)
    writer.send(None)
    try:
        for _, ts, frame in src.frames():
            t = ts / 1000.0
            for a, b, how in spans:
                if a <= t < b:
                    dx, dy = SHIFT[how]
                    M = np.array([[1, 0, dx * w], [0, 1, dy * h]], np.float32)
                    frame = cv2.warpAffine(frame, M, (w, h), borderValue=(0, 0, 0))
            writer.send(np.ascontiguousarray(frame[:, :, ::-1]))
    finally:
        writer.close()
        src.close()
    return Path(out)


def _subprocess(*args: str) -> tuple[int, str]:
    """``facecapges ARGS`` in a process of its own: (exit status, stderr)."""
    r = subprocess.run([sys.executable, "-m", "facecapges", *args], capture_output=True, text=True)
    return r.returncode, r.stderr


def run_live(video: Path, wav: Path, rec: Path, extra: tuple[str, ...] = (), runner=_subprocess) -> dict:
    """``facecapges live --video VIDEO --audio WAV --body --record REC`` (as fast as it goes); its report.
    ``runner(*args)`` runs the command and returns (exit status, stderr): a subprocess unless given (the test
    suite runs it in its own process, as it runs other commands: tests/runtime_helpers.cli)."""
    code, stderr = runner(
        "live", "--video", str(video), "--audio", str(wav), "--body", "--record", str(rec), "--force", *extra
    )
    if code != 0:
        raise RuntimeError(f"live --body failed: {stderr.strip()[-1500:]}")
    rep = json.loads((rec / "report.json").read_text())
    rep["stderr"] = stderr
    return rep


def recorded_pose(rec: Path) -> np.ndarray:
    """The upper-body pose (T, 47, 6) ``live --record`` wrote (motion.bvh)."""
    from facecapges.io.bvh import read_bvh

    b = read_bvh(rec / "motion.bvh")
    return motion_to_pose(b.skeleton, b.motion)[0]


def his_threshold(take: str | Path, skeleton_bvh: str | Path | None = None) -> float:
    """The pop threshold: the 99.9th percentile of his real motion's whole-body acceleration (first 80 %)."""
    skel, full = held_out_truth(take, skeleton_bvh or take, share=1.0)
    train = full[: int(round(len(full) * (1.0 - HELD_OUT)))]
    return rz.transition_threshold([motion_to_pose(skel, train)[0]], float(MODEL_FPS))


def handover_accelerations(pose: np.ndarray, events: list, threshold: float) -> dict:
    """At each hand-over, the largest whole-body acceleration over :data:`NEAR_HANDOVER` frames, over ``threshold``."""
    acc = rz.joint_acceleration(pose, float(MODEL_FPS))
    rows = []
    for frame, side, to in events:
        a, b = max(frame + NEAR_HANDOVER[0], 1), min(frame + NEAR_HANDOVER[1], len(acc) - 1)
        peak = float(acc[a:b].max()) if b > a else 0.0
        rows.append({"frame": int(frame), "side": side, "to": to, "peak_over_threshold": round(peak / threshold, 3)})
    interior = acc[1:-1]
    return {
        "threshold_rad_s2": round(threshold, 2),
        "handovers": rows,
        "pops_at_handovers": sum(r["peak_over_threshold"] > 1.0 for r in rows),
        "pops_per_min": round(float((interior > threshold).sum() / (len(pose) / MODEL_FPS / 60.0)), 2),
    }


def figures(skel: Skeleton, truth: np.ndarray, pose: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """:func:`compare` of the recorded pose with the truth (on the frames of ``mask`` when given)."""
    n = min(len(truth), len(pose))
    captured = pose_to_motion(skel, pose[:n])
    t = truth[:n]
    if mask is not None:
        m = np.asarray(mask[:n], bool)
        t, captured = t[m], captured[m]
    out = compare(skel, t, captured)
    out["camera"] = compare(skel, t, captured, frame="camera")
    return out


def on_body_mask(n: int, events: list, side: str) -> np.ndarray:
    """Frames (n,) on which ``side``'s arm followed the body (from the report's hand-over list), the
    blend settled: the first three half-lives after a hand-over to the body are left out."""
    from facecapges.runtime.body import HALFLIFE_S

    settle = int(round(3 * HALFLIFE_S * MODEL_FPS))
    m = np.zeros(n, bool)
    for frame, s, to in events:
        if s == side:
            m[frame:] = to == "body"
            m[frame : frame + settle] = False
    return m


def measure_live(
    take: str | Path, wav: str | Path, work: str | Path, skeleton_bvh: str | Path | None = None, runner=_subprocess
) -> dict:
    """The whole proof (module docstring): ``plain`` (the rendered video as it is) and ``leave`` (the
    hands leaving the frame), each with the truth comparison, the hand-overs and live's body report
    (``runner``: :func:`run_live`'s)."""
    work = Path(work)
    skel, truth, video, speech = render_truth(take, work, skeleton_bvh, wav)
    assert speech is not None
    thr = his_threshold(take, skeleton_bvh)
    out: dict = {"frames": len(truth)}
    left = leave_frame(video, work / "leave.mp4")
    for name, v in (("plain", video), ("leave", left)):
        rec = work / f"live_{name}"
        rep = run_live(v, speech, rec, runner=runner)
        pose = recorded_pose(rec)
        events = rep["body"]["handover_frames"]
        both = on_body_mask(len(pose), events, "Right") & on_body_mask(len(pose), events, "Left")
        res = {
            "all_frames": figures(skel, truth, pose),
            "both_arms_on_body": figures(skel, truth, pose, both) if both.sum() > 10 else None,
            "on_body_share": round(float(both.mean()), 3),
            "handover": handover_accelerations(pose, events, thr),
            "body": {k: v for k, v in rep["body"].items() if k != "handover_frames"},
            "latency_ms": {k: rep["latency_ms"][k] for k in ("capture", "body", "landmarks", "body_mix", "total")},
        }
        out[name] = res
    return out


def main(argv: list[str] | None = None) -> None:
    import argparse
    import tempfile

    ap = argparse.ArgumentParser(description="live --body against the truth on the held-out end of a known take")
    ap.add_argument("take", help="a BEAT BVH take")
    ap.add_argument("wav", help="its speech")
    ap.add_argument("--work", help="keep the videos and recordings here (default: a temporary folder)")
    args = ap.parse_args(argv)
    if args.work:
        print(json.dumps(measure_live(args.take, args.wav, args.work), indent=1))
        return
    with tempfile.TemporaryDirectory() as tmp:
        print(json.dumps(measure_live(args.take, args.wav, tmp), indent=1))


if __name__ == "__main__":
    main()
