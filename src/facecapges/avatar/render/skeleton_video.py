"""Side-by-side stick-figure videos of upper-body poses, with the speech muxed in.

:func:`render_skeleton_video` takes one or more pose sequences (T, 47, 6) rot6d in
:data:`~facecapges.skeleton.UPPER_BODY` order (e.g. real and generated), poses them
on a BVH :class:`~facecapges.skeleton.Skeleton` by forward kinematics and writes an
H.264 MP4 (yuv420p, plays in browsers) with an optional WAV as AAC.

* **Pose → joints**: every skeleton joint starts at its rest rotation (identity);
  the 47 UPPER_BODY joints take their rot6d; :func:`facecapges.skeleton.global_transforms`
  gives positions (skeleton units, BEAT: cm). Same FK as
  :func:`~facecapges.skeleton.pose_to_motion` + :func:`~facecapges.skeleton.joint_positions`,
  without the lossy round trip through Euler angles.
* **Drawn**: Hips and every descendant of Spine (torso, neck, Head/HeadEnd, arms,
  fingers incl. the fingertip end joints) — not the legs. The head is a circle
  around Head–HeadEnd.
* **View**: front view, orthographic: screen x = world X, screen y = world Y (up);
  the figure faces the viewer (BEAT: +Z towards the camera), so the character's right
  hand is on the viewer's left. One scale for all panels and frames, so the panels
  compare directly.
* **Drawing** with OpenCV (``cv2.line``, anti-aliased) into one BGR frame per time
  step, piped raw into the project's MP4 writer (:mod:`facecapges.io.mp4`); nothing is held in
  memory but the current frame. Colours: torso/head grey, right arm red, left arm
  blue (BGR order internally).
* Sequences of different lengths: the video lasts as long as the longest; a shorter
  panel holds its last pose. With audio, ffmpeg stops at the shorter of video and
  audio (``-shortest``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from facecapges.skeleton import Skeleton, upper_body_transforms
from facecapges.timing import MODEL_FPS

_RIGHT = (60, 60, 220)  # BGR
_LEFT = (220, 120, 40)
_TORSO = (90, 90, 90)


def pose_positions(skel: Skeleton, pose: np.ndarray) -> np.ndarray:
    """Joint positions (T, J_skel, 3) of upper-body poses (T, 47, 6) on ``skel`` (root at rest)."""
    return upper_body_transforms(skel, pose)[1]


def drawn_bones(skel: Skeleton) -> list[tuple[int, int, tuple[int, int, int]]]:
    """(parent, child, BGR colour) of every bone drawn: Hips and the Spine subtree."""
    spine = skel.index("Spine")
    bones = []
    for j in range(skel.n_joints):
        chain = skel.chain_to(skel.names[j])
        p = int(skel.parents[j])
        if p < 0 or spine not in chain:
            continue
        name = skel.names[j]
        side = not name.endswith("Shoulder")  # the Spine3 → Shoulder bone runs up the torso: grey
        colour = _RIGHT if side and name.startswith("Right") else _LEFT if side and name.startswith("Left") else _TORSO
        bones.append((p, j, colour))
    return bones


def _frame_mapper(all_xy: np.ndarray, panel_w: int, panel_h: int, margin: float, top: int):
    lo, hi = all_xy.min(0), all_xy.max(0)
    span = np.maximum(hi - lo, 1e-6)
    scale = min((panel_w * (1 - 2 * margin)) / span[0], (panel_h - top) * (1 - 2 * margin) / span[1])
    cx, cy = (lo + hi) / 2

    def to_px(xy: np.ndarray) -> np.ndarray:
        x = panel_w / 2 + (xy[..., 0] - cx) * scale
        y = top + (panel_h - top) / 2 - (xy[..., 1] - cy) * scale
        return np.stack([x, y], -1)

    return to_px, scale


def render_skeleton_video(
    poses: Sequence[np.ndarray],
    titles: Sequence[str],
    skeleton: Skeleton,
    out_path: str | Path,
    fps: float = float(MODEL_FPS),
    wav: str | Path | None = None,
    panel_size: tuple[int, int] = (480, 540),
    crf: int = 23,
    progress: bool = False,
) -> Path:
    """Render poses side by side (titled) to an MP4 at ``out_path``; returns the path.

    ``poses``: list of (T_i, 47, 6) rot6d; ``titles``: one per panel; ``wav``: optional
    audio muxed in (AAC). ``panel_size`` (width, height) in pixels, rounded to even.
    """

    if len(poses) == 0 or len(poses) != len(titles):
        raise ValueError(f"need one title per pose sequence, got {len(poses)} poses and {len(titles)} titles")
    pw, ph = (int(panel_size[0]) // 2) * 2, (int(panel_size[1]) // 2) * 2
    top = 40
    positions = [pose_positions(skeleton, p) for p in poses]
    bones = drawn_bones(skeleton)
    used = sorted({b[0] for b in bones} | {b[1] for b in bones})
    all_xy = np.concatenate([pos[:, used, :2].reshape(-1, 2) for pos in positions])
    to_px, _ = _frame_mapper(all_xy, pw, ph, 0.06, top)
    pix = [np.round(to_px(pos[..., :2]) * 4).astype(np.int32) for pos in positions]  # 2 fractional bits
    head, head_end = (
        skeleton.names.index("Head") if "Head" in skeleton.names else None,
        skeleton.names.index("HeadEnd") if "HeadEnd" in skeleton.names else None,
    )
    T = max(len(p) for p in positions)
    W, H = pw * len(poses), ph
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    from facecapges.io.mp4 import Mp4Writer

    writer = Mp4Writer(out, fps, audio=wav, crf=crf)
    background = _titled_background(titles, pw, W, H)
    from facecapges.progress import Progress

    try:
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task("rendering skeleton video", total=T)
            for t in range(T):
                frame = _frame(background, pix, bones, head, head_end, pw, t, t / fps)
                writer.write(frame)
                bar.advance(task)
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return out


def _titled_background(titles: Sequence[str], pw: int, W: int, H: int) -> np.ndarray:
    """The frame's background: light grey, each panel's title, a line between panels."""
    import cv2

    background = np.full((H, W, 3), 250, np.uint8)
    for k, title in enumerate(titles):
        cv2.putText(
            background, str(title), (k * pw + 12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (30, 30, 30), 2, cv2.LINE_AA
        )
        if k:
            cv2.line(background, (k * pw, 0), (k * pw, H), (200, 200, 200), 1)
    return background


def _frame(
    background: np.ndarray,
    pix: list[np.ndarray],
    bones: list,
    head: int | None,
    head_end: int | None,
    pw: int,
    t: int,
    seconds: float,
) -> np.ndarray:
    """Frame ``t``: each panel's skeleton (bones, head circle) over ``background``, and the time."""
    import cv2

    H, W = background.shape[:2]
    frame = background.copy()
    for k, px in enumerate(pix):
        f = px[min(t, len(px) - 1)]
        off = np.array([k * pw * 4, 0], np.int32)
        for a, b, colour in bones:
            cv2.line(frame, tuple(f[a] + off), tuple(f[b] + off), colour, 3, cv2.LINE_AA, shift=2)
        if head is not None and head_end is not None:
            c = (f[head] + f[head_end]) // 2 + off
            r = max(int(np.linalg.norm(f[head_end] - f[head]) * 0.6), 8)
            cv2.circle(frame, tuple(c), r, _TORSO, 3, cv2.LINE_AA, shift=2)
    cv2.putText(
        frame,
        f"{seconds:5.1f} s",
        (W - 110, H - 14),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.6,
        (80, 80, 80),
        1,
        cv2.LINE_AA,
    )
    return frame
