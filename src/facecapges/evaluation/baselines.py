"""Reference rows for the evaluation tables (thesis 5.7).

* **ground truth** — the held-out real motion itself (FGD ≈ 0 against itself,
  SRGR = 1 unweighted, L1DIV = the real motion's own diversity).
* **mean pose** — one static pose repeated: the per-joint mean over the training
  frames of the rot6d values, projected back onto valid rotations (Gram–Schmidt,
  :func:`facecapges.rotations.normalize_rot6d`). Its BeatAlign and L1DIV are the floor
  of a model that does not move.
* **random real segment** — real motion of the same speaker from another time: a
  window of the evaluated length cut at a random start from the training clips
  (or from the same clip outside the evaluated interval), so it moves like the
  speaker but is not synchronised with the evaluated speech.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from facecapges import rotations as rot


def ground_truth(real: np.ndarray) -> np.ndarray:
    """The reference row that *is* the real motion (a copy)."""
    return np.array(real, dtype=np.float32, copy=True)


def mean_pose(train_clips: Sequence[np.ndarray]) -> np.ndarray:
    """The mean training pose (J, 6) as valid rot6d."""
    frames = np.concatenate([np.asarray(c, np.float64) for c in train_clips], 0)
    if frames.ndim != 3 or frames.shape[-1] != 6 or len(frames) == 0:
        raise ValueError(f"train clips must be non-empty (T, J, 6), got {frames.shape}")
    return rot.normalize_rot6d(frames.mean(0)).astype(np.float32)


def mean_pose_sequence(train_clips: Sequence[np.ndarray], n_frames: int) -> np.ndarray:
    """The mean pose held for ``n_frames`` frames → (n_frames, J, 6)."""
    m = mean_pose(train_clips)
    return np.repeat(m[None], n_frames, axis=0)


def random_segment(
    pool: Sequence[np.ndarray],
    n_frames: int,
    rng: np.random.Generator | int = 0,
    exclude: tuple[int, int, int] | None = None,
) -> np.ndarray:
    """A random real window (n_frames, J, 6) from the clips in ``pool``.

    ``exclude = (clip_index, start, end)`` forbids windows overlapping frames
    ``start … end−1`` of that clip (the evaluated interval). Raises ValueError when no
    clip holds a window of that length outside the excluded interval.
    """
    rng = np.random.default_rng(rng)
    candidates: list[tuple[int, int]] = []
    for ci, c in enumerate(pool):
        for s in range(0, len(c) - n_frames + 1):
            if exclude is not None and exclude[0] == ci and s < exclude[2] and s + n_frames > exclude[1]:
                continue
            candidates.append((ci, s))
    if not candidates:
        raise ValueError(f"no real segment of {n_frames} frames outside the evaluated interval")
    ci, s = candidates[int(rng.integers(len(candidates)))]
    return np.asarray(pool[ci][s : s + n_frames], np.float32).copy()
