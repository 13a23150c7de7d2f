"""Body and hands from ordinary video: MediaPipe pose + hand landmarkers → BEAT BVH.

:class:`BodyLandmarker` runs MediaPipe's PoseLandmarker (BlazePose full) and
HandLandmarker (two hands) in VIDEO mode on the bundles of
:mod:`facecapges.capture.body_models`. :func:`capture_body` samples the video at
15 fps (the frame nearest each 1/15 s), collects pose world landmarks and hand
world landmarks (each hand given to the subject's arm whose pose wrist is nearest
in the image), solves the BEAT upper-body rotations (:mod:`.body_solve`) and writes
the same 15 fps BEAT BVH the rest of the product reads.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path
from facecapges.capture.body_solve import WRIST, BodyLandmarks, BodySolve, smooth_for_style, solve
from facecapges.errors import UserError
from facecapges.skeleton import Skeleton
from facecapges.timing import MODEL_FPS


class BodyLandmarker:
    """Pose and hand landmarkers in VIDEO mode. Use as a context manager."""

    def __init__(self, min_confidence: float = 0.5):
        os.environ.setdefault("GLOG_minloglevel", "2")
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
        from mediapipe.tasks.python.core.base_options import BaseOptions
        from mediapipe.tasks.python.vision import hand_landmarker as hl
        from mediapipe.tasks.python.vision import pose_landmarker as pl
        from mediapipe.tasks.python.vision.core.vision_task_running_mode import VisionTaskRunningMode

        from facecapges.capture.landmarks import create_task

        pose_path, hand_path = model_path(POSE_TASK), model_path(HAND_TASK)
        mode = VisionTaskRunningMode.VIDEO
        self._pose, self._hand = create_task(
            lambda: (
                pl.PoseLandmarker.create_from_options(
                    pl.PoseLandmarkerOptions(
                        base_options=BaseOptions(model_asset_path=str(pose_path)),
                        running_mode=mode,
                        num_poses=1,
                        min_pose_detection_confidence=min_confidence,
                        min_pose_presence_confidence=min_confidence,
                        min_tracking_confidence=min_confidence,
                    )
                ),
                hl.HandLandmarker.create_from_options(
                    hl.HandLandmarkerOptions(
                        base_options=BaseOptions(model_asset_path=str(hand_path)),
                        running_mode=mode,
                        num_hands=2,
                        min_hand_detection_confidence=min_confidence,
                        min_hand_presence_confidence=min_confidence,
                        min_tracking_confidence=min_confidence,
                    )
                ),
            ),
            "MediaPipe cannot load the body-capture models",
        )
        self._last_ts = -1
        self._first = True
        # MediaPipe's C functions called on this thread (not through its dispatcher thread), every frame converted
        # into one kept image, as the face landmarker does (capture.landmarks: DirectCalls, FrameImages; issue 36)
        from facecapges.capture.landmarks import DirectCalls, FrameImages

        self._direct_pose = DirectCalls.of(self._pose, "MpPoseLandmarker")
        self._direct_hand = DirectCalls.of(self._hand, "MpHandLandmarker")
        direct = self._direct_pose is not None and self._direct_hand is not None
        if not direct:
            self._direct_pose = self._direct_hand = None
        self._images = FrameImages(direct)

    def _detect(self, image, ts: int):
        """Both landmarkers' results on ``image``: MediaPipe's ``detect_for_video`` of each (its C calls on this
        thread where :class:`~facecapges.capture.landmarks.DirectCalls` has them: the same results)."""
        if self._direct_pose is None or self._direct_hand is None:
            return self._pose.detect_for_video(image, ts), self._hand.detect_for_video(image, ts)
        from mediapipe.tasks.python.vision import hand_landmarker as hl
        from mediapipe.tasks.python.vision import pose_landmarker as pl

        pr = self._direct_pose.result(
            self._pose, image, ts, pl.MpPoseLandmarkerResultC(), pl.PoseLandmarkerResult.from_ctypes
        )
        hr = self._direct_hand.result(
            self._hand, image, ts, hl.MpHandLandmarkerResultC(), hl.HandLandmarkerResult.from_ctypes
        )
        return pr, hr

    def detect(self, frame_bgr: np.ndarray, timestamp_ms: int) -> dict:
        """One BGR frame → {'pose', 'visibility', 'pose_image', 'hands': [(world (21,3), image (21,3), score)]}."""
        ts = max(int(timestamp_ms), self._last_ts + 1)
        self._last_ts = ts
        image = self._images(frame_bgr)
        if self._first:  # MediaPipe's C++ logs a projection warning on the first frame
            from facecapges.capture.landmarks import NativeStderrToFile

            with NativeStderrToFile() as log:
                pr, hr = self._detect(image, ts)
            if log.errors:
                sys.stderr.write(log.errors)
            self._first = False
        else:
            pr, hr = self._detect(image, ts)
        out: dict = {"pose": None, "visibility": None, "pose_image": None, "hands": []}
        if pr.pose_world_landmarks:
            w = pr.pose_world_landmarks[0]
            out["pose"] = np.array([(p.x, p.y, p.z) for p in w], np.float64)
            out["visibility"] = np.array([p.visibility or 0.0 for p in w], np.float64)
            out["pose_image"] = np.array([(p.x, p.y, p.z) for p in pr.pose_landmarks[0]], np.float64)
        for k, wl in enumerate(hr.hand_world_landmarks):
            img = np.array([(p.x, p.y, p.z) for p in hr.hand_landmarks[k]], np.float64)
            score = float(hr.handedness[k][0].score) if k < len(hr.handedness) and hr.handedness[k] else 1.0
            out["hands"].append((np.array([(p.x, p.y, p.z) for p in wl], np.float64), img, score))
        return out

    def close(self) -> None:
        images = getattr(self, "_images", None)
        if images is not None:
            images.kept = None  # MediaPipe's image, freed with its task
        for t in (getattr(self, "_pose", None), getattr(self, "_hand", None)):
            if t is not None:
                t.close()
        self._pose = self._hand = None

    def __enter__(self) -> BodyLandmarker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def assign_hands(det: dict) -> tuple[list[np.ndarray | None], list[float]]:
    """Each found hand to the subject's right [0] / left [1] arm whose pose wrist is nearest in the image."""
    hands: list[np.ndarray | None] = [None, None]
    scores = [0.0, 0.0]
    if det["pose_image"] is None:
        return hands, scores
    wr = [det["pose_image"][WRIST[s], :2] for s in ("Right", "Left")]
    for world, img, score in det["hands"]:
        d = [float(np.linalg.norm(img[0, :2] - w)) for w in wr]
        s = int(np.argmin(d))
        if d[s] > 0.15:  # farther than ~15 % of the image from either wrist: not this person's hand
            continue
        if hands[s] is None or score > scores[s]:
            hands[s], scores[s] = world, score
    return hands, scores


def collect_landmarks(
    video: str | Path,
    fps: float = float(MODEL_FPS),
    max_frames: int | None = None,
    progress: Callable[[int, int | None], None] | None = None,
) -> tuple[BodyLandmarks, dict]:
    """Pose and hand landmarks of ``video`` sampled at ``fps``; also a summary (frames, found shares, ms/frame)."""
    from facecapges.capture.video import open_source

    src = open_source(str(video))
    if src.is_camera:
        src.close()
        raise UserError("capture-body reads a video file, not a camera")
    n_out = None if src.n_frames is None else max(1, int(np.floor(src.n_frames / src.fps * fps + 1e-6)))
    if max_frames is not None:
        n_out = max_frames if n_out is None else min(n_out, max_frames)
    poses, vis, hands, scores, images = [], [], [], [], []
    ms = []
    next_t = 0  # next output frame index
    try:
        with BodyLandmarker() as lm:
            for i, ts, frame in src.frames():
                if n_out is not None and next_t >= n_out:
                    break
                # the video frame nearest each output time (a slow video's frame serves several)
                det = None
                while (n_out is None or next_t < n_out) and (i + 0.5) * 1000.0 / src.fps > next_t * 1000.0 / fps:
                    if det is None:
                        t0 = time.perf_counter()
                        det = lm.detect(frame, int(ts))
                        ms.append((time.perf_counter() - t0) * 1000.0)
                        h, s = assign_hands(det)
                    poses.append(det["pose"] if det["pose"] is not None else np.full((33, 3), np.nan))
                    images.append(det["pose_image"] if det["pose_image"] is not None else np.full((33, 3), np.nan))
                    vis.append(det["visibility"] if det["visibility"] is not None else np.zeros(33))
                    hands.append(np.stack([x if x is not None else np.full((21, 3), np.nan) for x in h]))
                    scores.append(s)
                    next_t += 1
                    if progress is not None:
                        progress(next_t, n_out)
    finally:
        src.close()
    if not poses:
        raise UserError(f"{video}: no frame could be read from the video")
    lms = BodyLandmarks(
        pose=np.stack(poses),
        visibility=np.stack(vis),
        hands=np.stack(hands),
        hand_score=np.array(scores),
        fps=fps,
        pose_image=np.stack(images),
        image_size=(int(src.width), int(src.height)),
    )
    seen = np.isfinite(lms.pose).all(axis=(1, 2))
    summary = {
        "frames": lms.n_frames,
        "fps": fps,
        "pose_found": float(seen.mean()),
        "hands_found": [float((lms.hand_score[:, s] > 0).mean()) for s in range(2)],
        "both_hands_found": float((lms.hand_score > 0).all(axis=1).mean()),
        "ms_per_frame": float(np.median(ms)) if ms else float("nan"),
        "video": {"width": src.width, "height": src.height, "fps": src.fps},
    }
    return lms, summary


def capture_body(
    video: str | Path,
    out: str | Path,
    skeleton: Skeleton,
    max_frames: int | None = None,
    progress: Callable[[int, int | None], None] | None = None,
    for_style: bool = False,
) -> tuple[BodySolve, dict]:
    """Video → BEAT BVH at 15 fps on ``skeleton``. Returns the solve and a summary (its ``warning``: the
    :func:`check_usable` warning or None). A video in which nothing usable was seen is refused (a
    :class:`~facecapges.errors.UserError`) before ``out`` is written. ``for_style`` (``styles build
    --video``): the motion is smoothed further for a style's database (:func:`smooth_for_style`)."""
    from facecapges.io.bvh import write_bvh
    from facecapges.skeleton import pose_to_motion

    lms, summary = collect_landmarks(video, float(MODEL_FPS), max_frames=max_frames, progress=progress)
    if summary["pose_found"] == 0.0:
        raise UserError(f"{video}: no person found in any frame (the pose landmarker saw no body)")
    res = solve(skeleton, lms)
    if for_style:
        res = BodySolve(pose=smooth_for_style(res.pose, float(MODEL_FPS)), confidence=res.confidence)
    conf = res.confidence.mean(axis=0)
    summary["arm_confidence"] = float(np.mean([conf[k] for k in range(3, 47) if k in (4, 5, 26, 27)]))
    summary["joint_confidence"] = conf.tolist()
    summary["warning"] = check_usable(video, summary)  # refused before anything is written
    write_bvh(out, skeleton, pose_to_motion(skeleton, res.pose), float(MODEL_FPS))
    return res, summary


CARD_JOINTS = ("Spine", "RightArm", "RightForeArm", "RightHand", "LeftArm", "LeftForeArm", "LeftHand")


def seen_report(video: str | Path, summary: dict) -> dict:
    """How well a video's motion was seen, for a style's model card: the video's name, its frames, the
    shares of frames with the person / each hand / both hands found, and the mean confidence of the
    driven joints (:data:`CARD_JOINTS`) and of each hand's fingers."""
    from facecapges.skeleton import UPPER_BODY

    conf = summary["joint_confidence"]
    joints = {n: round(float(conf[UPPER_BODY.index(n)]), 2) for n in CARD_JOINTS}
    for side in ("Right", "Left"):
        fingers = [
            c for n, c in zip(UPPER_BODY, conf, strict=True) if n.startswith(f"{side}Hand") and n != f"{side}Hand"
        ]
        joints[f"{side} fingers"] = round(float(np.mean(fingers)), 2)
    return {
        "video": Path(video).name,
        "frames": int(summary["frames"]),
        "person_found": round(float(summary["pose_found"]), 3),
        "right_hand_found": round(float(summary["hands_found"][0]), 3),
        "left_hand_found": round(float(summary["hands_found"][1]), 3),
        "both_hands_found": round(float(summary["both_hands_found"]), 3),
        "joint_confidence": joints,
    }


MIN_USABLE = 0.2  # below this share of frames with the person found, or mean arm confidence, nothing usable was seen


def check_usable(video: str | Path, summary: dict) -> str | None:
    """Raise a UserError when nothing usable was seen; return a warning when the arms were mostly out of view."""
    if summary["pose_found"] < MIN_USABLE or summary["arm_confidence"] < MIN_USABLE:
        raise UserError(
            f"{video}: nothing usable was seen (person found in {summary['pose_found']:.0%} of the frames, "
            f"mean arm confidence {summary['arm_confidence']:.2f}); film the upper body and hands facing the camera"
        )
    if summary["arm_confidence"] < 0.5:
        return (
            f"{video}: the arms were out of view most of the time (mean arm confidence {summary['arm_confidence']:.2f})"
        )
    return None


def in_frame_visibility(det: dict) -> np.ndarray:
    """The pose landmarks' visibility (33,) with every landmark outside the image set to 0 (the landmarker
    still places a wrist that left the frame, guessed, sometimes with a high visibility); zeros with no person."""
    if det["visibility"] is None or det["pose_image"] is None:
        return np.zeros(33)
    xy = det["pose_image"][:, :2]
    inside = ((xy >= 0.0) & (xy <= 1.0)).all(axis=1)
    return np.where(inside, det["visibility"], 0.0)
