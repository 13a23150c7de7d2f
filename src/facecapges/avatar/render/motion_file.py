"""``facecapges render`` as a function: a BVH (+ face JSON, audio) → MP4 of an avatar.

:func:`render_motion_file` checks every output and input before the work, then renders
our avatar (built from the BVH's skeleton, or an avatar ``.glb`` of ours) with
:func:`facecapges.avatar.render.video.render_video`, or a VRM / humanoid GLB the same way
(:class:`facecapges.avatar.vrm.view.VrmDriver` gives its page and frames). The face is the face JSON's weights;
without one, the jaw and lips follow the audio (:mod:`facecapges.capture.speech_mouth`).
This module imports nothing heavy, so the command line reads :class:`RenderOptions`'
defaults for ``--help``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from facecapges.errors import echo

SIZE_RANGE = (16, 4096)  # pixels, either side


@dataclass
class RenderOptions:
    """The options of ``render`` (``facecapges render --help`` says what each does)."""

    bvh: Path
    out: Path
    face: Path | None = None
    audio: Path | None = None
    avatar_glb: Path | None = None
    contact_sheet: Path | None = None
    size: str = "640x480"
    force: bool = False


def parse_render_size(size: str) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` → (width, height), each within :data:`SIZE_RANGE`."""
    from facecapges.errors import UserError

    try:
        width, height = (int(x) for x in size.lower().split("x"))
    except ValueError:
        raise UserError(f"--size must be WIDTHxHEIGHT, got {size!r}") from None
    lo, hi = SIZE_RANGE
    if not (lo <= width <= hi and lo <= height <= hi):
        raise UserError(f"--size {size} is out of range")
    return width, height


def _shown_face(o: RenderOptions, fps: float, T: int):
    """The face JSON's weights; without one, jaw and lips from the speech (capture.speech_mouth)."""
    if o.face is None and o.audio is not None:
        from facecapges.capture.speech_mouth import speech_frames, speech_mouth_track
        from facecapges.io.audio import load_audio

        return speech_mouth_track(speech_frames(load_audio(o.audio), fps, T), fps)
    from facecapges.avatar.vrm.view import face_weights

    return face_weights(o.face, fps, T)


def _our_avatar(o: RenderOptions, skeleton) -> tuple[bytes, list[str]]:
    """(GLB bytes, its joint names): ``o.avatar_glb`` (one of ours), else built from ``skeleton``."""
    from facecapges.errors import file_error, require_file

    if o.avatar_glb is None:
        from facecapges.avatar.gltf import avatar_glb

        return avatar_glb(skeleton), list(skeleton.names)
    from facecapges.avatar.gltf_check import read_avatar_file
    from facecapges.avatar.vrm.glb import split_glb

    p = require_file(o.avatar_glb, "avatar")
    glb = read_avatar_file(p)
    doc, _ = split_glb(glb, str(p))  # self-contained and well-formed (avatar.gltf_check)
    names = ((doc.get("extras") or {}).get("facecapges") or {}).get("joint_names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise file_error(p, "not a facecapges avatar .glb (no joint_names in its extras)")
    return glb, names


def render_motion_file(o: RenderOptions, say: Callable[..., None] = echo) -> dict:
    """The whole ``render`` command (module docstring); returns the renderer's figures.

    ``say`` gets the avatar a VRM is (``avatar: …``) and a line per file written."""
    import numpy as np

    from facecapges.arkit import ARKIT_NAMES
    from facecapges.avatar.body import check_skeleton
    from facecapges.avatar.render.video import bvh_quaternions, contact_sheet, our_avatar, render_video
    from facecapges.avatar.vrm.view import is_vrm_file
    from facecapges.errors import UserError, check_output_file, require_file
    from facecapges.io.bvh import read_bvh

    check_output_file(o.out, o.force)
    if o.contact_sheet is not None:
        check_output_file(o.contact_sheet, o.force)
    if o.audio is not None:  # used only at the final mux: check it before the whole render
        from facecapges.io.audio import check_audio

        check_audio(o.audio)
    width, height = parse_render_size(o.size)
    motion = read_bvh(o.bvh)
    check_skeleton(motion.skeleton, str(o.bvh))
    if o.audio is not None:
        require_file(o.audio, "audio")
    if o.face is not None:
        require_file(o.face, "face JSON")
    vrm = o.avatar_glb is not None and is_vrm_file(require_file(o.avatar_glb, "avatar"))
    if o.audio is None and o.face is None:  # after the checks: a refused command says only why
        from facecapges.errors import echo_warning

        echo_warning(
            "warning: no --audio and no --face: the video will be silent and the mouth still "
            "(pass --audio SPEECH.wav: its sound, and the jaw and lips follow it; or --face FACE.json)"
        )
    if vrm and o.avatar_glb is not None:
        from facecapges.avatar.vrm.view import VrmDriver, bvh_local_matrices

        driver = VrmDriver.from_file(o.avatar_glb, motion.skeleton)
        say(f"avatar: {driver.describe()}")
        if o.contact_sheet is not None:
            raise UserError("--contact-sheet needs our own avatar (its 52 morph targets), not a VRM")
        weights = _shown_face(o, motion.fps, len(motion.motion))
        quats, shown = driver.frames(bvh_local_matrices(motion.skeleton, motion.motion), weights)
        figures = render_video(
            driver.page(), quats, shown, motion.fps, o.out, audio=o.audio, width=width, height=height
        )
        say(f"{o.out}: {figures['frames']} frames at {motion.fps:g} fps rendered in {figures['total_s']:.1f} s")
        return figures
    glb, joint_names = _our_avatar(o, motion.skeleton)
    quats = bvh_quaternions(joint_names, motion.skeleton, motion.motion, str(o.bvh))
    weights = _shown_face(o, motion.fps, quats.shape[0])
    figures = render_video(
        our_avatar(glb), quats, np.clip(weights, 0.0, 1.0), motion.fps, o.out, audio=o.audio, width=width, height=height
    )
    say(f"{o.out}: {figures['frames']} frames at {motion.fps:g} fps rendered in {figures['total_s']:.1f} s")
    if o.contact_sheet is not None:
        contact_sheet(glb, list(ARKIT_NAMES), o.contact_sheet)
        say(f"{o.contact_sheet}: contact sheet of the 52 blendshapes")
    return figures
