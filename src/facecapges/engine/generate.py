"""The one whole-recording generation loop, through the same per-frame path as live use.

:func:`generate_blocks` — which ``generate``, ``eval`` and ``ablate`` share — runs an engine's stream
frame by frame from its cold start (or a given history) over a recording's inputs
(:mod:`facecapges.engine.inputs`); :func:`generate_poses` is the same over inputs held in memory.
Long recordings stream block by block (:meth:`~facecapges.engine.inputs.StreamedInputs.blocks`), so
memory stays flat in the input's length.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator

import numpy as np

from facecapges.engine.contract import GestureEngine
from facecapges.engine.inputs import FrameInputs
from facecapges.errors import UserError
from facecapges.skeleton import N_JOINTS


def generate_blocks(
    engine: GestureEngine,
    blocks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
    n_frames: int,
    progress: bool = True,
    timing_ms: list | None = None,
    intensity: float = 1.0,
    history: np.ndarray | None = None,
) -> Iterator[np.ndarray]:
    """The one whole-recording generation loop: one stream of ``engine`` over consecutive input blocks
    ``(audio, face, head)`` at its rate; yields pose blocks (n, 47, 6), never a non-finite one.

    The stream starts from the engine's cold-start window, or from ``history`` (n, 47, 6) given as the
    poses before the first frame (evaluation's other samples). ``timing_ms`` (a list) receives the
    engine's ms per frame at the end; ``intensity``: the stream's dial (:mod:`facecapges.engine.intensity`)."""
    gen = engine.streaming()
    if history is not None:
        gen.reset(initial_pose=history)
    gen.intensity = intensity
    from facecapges.engine.threads import limit_threads

    limits = limit_threads(1)  # one small step at a time: more threads only spin (torch's if loaded, BLAS's)
    bar = None
    if progress:
        from facecapges.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task("generating" if history is None else "generating (other start)", total=n_frames)
    spent = 0.0
    try:
        for audio, face, head in blocks:
            out = np.empty((len(audio), N_JOINTS, 6), np.float32)
            t0 = time.perf_counter()
            for t in range(len(audio)):
                out[t] = gen.step(audio[t], face[t], head[t])
            spent += time.perf_counter() - t0
            if not np.isfinite(out).all():  # never emit NaN: this would be a model bug
                raise UserError("the model produced non-finite poses; the checkpoint is unusable")
            if bar is not None:
                bar.advance(task, len(audio))
            yield out
    finally:
        limits.restore_original_limits()
        if bar is not None:
            bar.stop()
    if timing_ms is not None:
        timing_ms.append(spent * 1000 / max(n_frames, 1))


def generate_poses(
    engine: GestureEngine, inputs: FrameInputs, progress: bool = True, history: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """:func:`generate_blocks` over inputs in memory: poses (T, 47, 6) and the engine's ms per frame."""
    ms: list[float] = []
    blocks = generate_blocks(
        engine, [(inputs.audio, inputs.face, inputs.head)], inputs.n_frames, progress, ms, history=history
    )
    poses = list(blocks)
    out = np.concatenate(poses) if poses else np.empty((0, N_JOINTS, 6), np.float32)
    return out, ms[0]
