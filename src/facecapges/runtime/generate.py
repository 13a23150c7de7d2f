"""``facecapges generate`` as a function: a recording's speech (+ face, head) → BVH, face JSON, VRM Animation.

:func:`generate_recording` checks every output before the work, plans the inputs
at the checkpoint's rate (:meth:`facecapges.engine.contract.GestureEngine.plan_inputs`), generates block by
block through the one generation loop (:func:`facecapges.engine.generate.generate_blocks`; memory flat in
the recording's length) and writes:

* ``out`` — the gestures on the checkpoint's BEAT skeleton at the model rate (BVH);
* ``face_out`` — the face to show with them (face JSON): the ``face`` track resampled,
  or without one, jaw and lips from the speech (:class:`facecapges.capture.speech_mouth.SpeechMouth`);
* ``vrma`` — the gestures and the face (the ``face`` weights, or jaw and lips from the speech)
  as VRM Animation for any VRM avatar.

It returns the summary ``generate --json`` prints. This module imports nothing heavy, so the
command line reads :class:`GenerateOptions`' defaults for ``--help``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from facecapges.errors import echo, echo_warning


@dataclass
class GenerateOptions:
    """The options of ``generate`` (``facecapges generate --help`` says what each does)."""

    audio: Path
    out: Path
    face: Path | None = None
    head: Path | None = None
    checkpoint: Path | None = None
    style: str | None = None
    intensity: float = 1.0
    face_out: Path | None = None
    json_out: bool = False
    vrma: Path | None = None
    vrma_face: str = "presets"
    force: bool = False


def _check(o: GenerateOptions) -> None:
    """Every check of ``o`` that needs no model: intensity, outputs (existing, folder, unwritable), inputs."""
    from facecapges.engine.intensity import check_intensity
    from facecapges.errors import check_output_file, require_file
    from facecapges.io.audio import check_audio

    check_intensity(o.intensity)
    check_output_file(o.out, o.force)  # before the work: existing, folder, unwritable
    if o.face_out is not None:
        check_output_file(o.face_out, o.force)
    if o.vrma is not None:
        from facecapges.avatar.vrm.animation import check_face_mode

        check_output_file(o.vrma, o.force)
        check_face_mode(o.vrma_face)
    check_audio(o.audio)
    if o.face is not None:
        require_file(o.face, "face JSON file")
    if o.head is not None:
        require_file(o.head, "head rotation file")


def _summary(o: GenerateOptions, ckpt, inputs, ms: float, say: Callable[..., None]) -> dict:
    """The summary of a ``generate`` run, said as a line (or as JSON with ``o.json_out``)."""
    import json

    n = inputs.n_frames
    summary = {
        "out": str(o.out),
        "frames": int(n),
        "fps": ckpt.fps,
        "duration_s": round(n / ckpt.fps, 3),
        "ms_per_frame": round(ms, 3),
        "checkpoint": str(ckpt.path),
        "warnings": inputs.notes,
    }
    if o.json_out:
        say(json.dumps(summary))
    else:
        say(
            f"wrote {o.out}: {summary['frames']} frames at {ckpt.fps} fps "
            f"({summary['duration_s']} s), {ms:.2f} ms/frame"
        )
    return summary


def generate_recording(
    o: GenerateOptions, say: Callable[..., None] = echo, warn: Callable[[str], None] = echo_warning
) -> dict:
    """The whole ``generate`` command (module docstring); returns its summary.

    ``say(text, err=False)`` gets the result line (the summary as JSON with ``o.json_out``),
    ``warn`` the input planner's warnings."""
    import numpy as np

    from facecapges.io.bvh import BvhWriter
    from facecapges.rotations import normalize_rot6d
    from facecapges.skeleton import pose_to_motion

    _check(o)  # every check before the model loads: a wrong path or file type is reported in a second
    from facecapges.engine.generate import generate_blocks
    from facecapges.styles import load_style

    ckpt = load_style(o.checkpoint, o.style)
    inputs = ckpt.plan_inputs(o.audio, o.face, o.head)  # at the checkpoint's rate
    for note in inputs.notes:
        warn(f"warning: {note}")
    skel = ckpt.skeleton
    timing_ms: list[float] = []
    mouth, spoken = None, []
    if (o.face_out is not None or o.vrma is not None) and o.face is None:  # no face: jaw and lips from the speech
        from facecapges.capture.speech_mouth import SpeechMouth

        mouth = SpeechMouth(ckpt.fps)

    def blocks():
        for a, f, h in inputs.blocks():
            if mouth is not None:
                spoken.extend(mouth.step(x) for x in a)
            yield a, f, h

    kept = []  # the poses, only when a .vrma is asked for
    with BvhWriter(o.out, skel, inputs.n_frames, ckpt.fps) as bvh:  # block by block: memory flat in length
        for poses in generate_blocks(ckpt, blocks(), inputs.n_frames, not o.json_out, timing_ms, o.intensity):
            poses = normalize_rot6d(poses)
            bvh.write(pose_to_motion(skel, poses))
            if o.vrma is not None:
                kept.append(poses)
    shown = inputs.face if mouth is None else np.stack(spoken).astype(np.float32)  # the face the viewer shows
    if o.face_out is not None:
        from facecapges.io.face_json import write_face_json

        write_face_json(o.face_out, shown, ckpt.fps, inputs.head)
    if o.vrma is not None:
        from facecapges.avatar.vrm.animation import write_pose_vrma

        write_pose_vrma(o.vrma, skel, np.concatenate(kept), ckpt.fps, shown, o.vrma_face)
        say(f"wrote {o.vrma} (VRM Animation)", err=o.json_out)
    summary = _summary(o, ckpt, inputs, timing_ms[0], say)
    return summary
