"""``facecapges prepare`` and ``facecapges export``: BEAT files → cache → BVH."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import FORCE_OUT, QUIET_BAR
from facecapges.errors import UserError
from facecapges.timing import MODEL_FPS


def parse_speakers(text: str) -> list[int] | None:
    """``"2,4,6,8"`` → [2, 4, 6, 8]; empty → None (all speakers)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    try:
        return [int(p) for p in parts] or None
    except ValueError:
        raise UserError(f"--speakers must be comma-separated speaker ids like 2,4,6,8, got {text!r}") from None


def _target_skeleton(path: Path | None):
    """The BEAT skeleton to write retargeted poses on: a BVH's, or the default style's."""
    from facecapges.data.beat import check_skeleton

    if path is None:
        from facecapges.styles import load_skeleton

        return load_skeleton()
    from facecapges.io.bvh import read_bvh

    skel = read_bvh(path).skeleton
    check_skeleton(skel, path, None)
    return skel


BEAT_ROOT = typer.Argument(
    help="Folder with BEAT files ({spk}_{name}_{type}_{start}_{end}.bvh/.wav/.json/.txt/.csv), searched "
    "recursively; BEAT2 takes (smplxflame_30/*.npz beside wave16k/*.wav) are converted to the BEAT skeleton.",
)
CACHE_OUT = typer.Option("--out", help="Cache folder to create.")
SPEAKERS = typer.Option("--speakers", help="Comma-separated BEAT speaker ids to keep, e.g. 2,4,6,8 (default: all).")
FPS = typer.Option("--fps", help="Frame rate of the cache (BEAT rule: 120 fps keeps every 8th frame).")
MOCAP = typer.Option(
    "--mocap",
    help="BVH file or folder of another skeleton, each with a same-named .wav; retargeted onto BEAT. Repeatable.",
)
JOINT_MAP = typer.Option(
    "--map", help="Joint map for --mocap: zeggs, beat or a JSON file (default: detected from the joint names)."
)
MOCAP_SPEAKER = typer.Option(
    "--mocap-speaker", help="Speaker id of the --mocap clips (100 or more; default: the joint map's, ZEGGS 100)."
)
JOINTS9 = typer.Option(
    "--joints9", help="Reduced-joint .npy file or folder (T, 9, 7), each with a same-named .wav. Repeatable."
)
LAYOUT = typer.Option("--layout", help="Joint layout of --joints9: zeggs9 (default) or a JSON file.")
JOINTS9_SPEAKER = typer.Option(
    "--joints9-speaker", help="Speaker id of the --joints9 clips (100 or more; default: the layout's, ZEGGS 100)."
)
TARGET = typer.Option(
    "--target",
    help="BEAT-skeleton BVH the other sources and BEAT2 takes are written on "
    "(default: the first BEAT BVH, else the default style's skeleton).",
)
PREPARE_FORCE = typer.Option("--force", help="Replace an existing cache at --out.")


def prepare(
    out: Annotated[Path, CACHE_OUT],
    beat_root: Annotated[Path | None, BEAT_ROOT] = None,
    speakers: Annotated[str, SPEAKERS] = "",
    fps: Annotated[float, FPS] = float(MODEL_FPS),
    mocap: Annotated[list[Path] | None, MOCAP] = None,
    joint_map: Annotated[str | None, JOINT_MAP] = None,
    mocap_speaker: Annotated[int | None, MOCAP_SPEAKER] = None,
    joints9: Annotated[list[Path] | None, JOINTS9] = None,
    layout: Annotated[str | None, LAYOUT] = None,
    joints9_speaker: Annotated[int | None, JOINTS9_SPEAKER] = None,
    target: Annotated[Path | None, TARGET] = None,
    force: Annotated[bool, PREPARE_FORCE] = False,
    quiet: Annotated[bool, QUIET_BAR] = False,
) -> None:
    """Build a training cache (pose, joint masks, head, face, semantic, emotion, audio, splits, stats) from BEAT
    files and mocap of other skeletons."""
    from facecapges.data.prepare import needs_target
    from facecapges.data.prepare import prepare as run_prepare
    from facecapges.errors import check_output_dir

    check_output_dir(out)  # a file in the way or a folder that cannot be written: now, not after the work
    target_skel = None
    if ((mocap or joints9) and (target is not None or beat_root is None)) or needs_target(beat_root):
        target_skel = _target_skeleton(target)  # BEAT2 takes without a BEAT BVH need it too
    index = run_prepare(
        beat_root,
        out,
        speakers=parse_speakers(speakers),
        fps=fps,
        force=force,
        progress=not quiet,
        mocap=list(mocap or []),
        joints9=list(joints9 or []),
        joint_map=joint_map,
        layout=layout,
        mocap_speaker=mocap_speaker,
        joints9_speaker=joints9_speaker,
        target=target_skel,
    )
    _print_prepared(index, out)


def _print_prepared(index: dict, out: Path) -> None:
    """The warnings, the summary table and the totals of a cache ``prepare`` wrote."""
    from rich.console import Console

    from facecapges.data.prepare import summary_table

    console = Console()
    for w in index.get("warnings", []):
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(summary_table(index))
    n = len(index["clips"])
    frames = sum(c["n_frames"] for c in index["clips"])
    audio_only = sum(1 for s in index["skipped"] if s["reason"] == "audio only")
    console.print(
        f"{n} clip{'s' if n != 1 else ''}, {frames} frames, {frames / index['fps']:.1f} s"
        f"{f', {audio_only} audio only' if audio_only else ''} → {out}"
    )


SRC = typer.Argument(help="BVH file of any skeleton (joint names mapped by --map).")
RETARGET_OUT = typer.Option("--out", help="BVH file to write, on the BEAT skeleton.")
RETARGET_FPS = typer.Option("--fps", help="Resample to this frame rate (default: the source's).")
RETARGET_JOINT_MAP = typer.Option(
    "--map", help="Joint map: zeggs, beat or a JSON file (default: detected from the joint names)."
)
RETARGET_TARGET = typer.Option(
    "--target", help="BEAT-skeleton BVH to write on (default: the skeleton of the default style)."
)


def retarget(
    src: Annotated[Path, SRC],
    out: Annotated[Path, RETARGET_OUT],
    fps: Annotated[float | None, RETARGET_FPS] = None,
    joint_map: Annotated[str | None, RETARGET_JOINT_MAP] = None,
    target: Annotated[Path | None, RETARGET_TARGET] = None,
    force: Annotated[bool, FORCE_OUT] = False,
) -> None:
    """Map a BVH of another skeleton onto the BEAT 47-joint upper body (joint names + rest-pose correction).

    World-space bone directions of every mapped joint match the source's; joints the
    source lacks stay at rest (listed). The root's translation and the hips' rotation
    are not carried over (BEAT's pose is the upper body relative to the pelvis).
    """
    from facecapges.data.retarget import retarget_bvh
    from facecapges.errors import refuse_overwrite, require_file
    from facecapges.io.bvh import write_bvh
    from facecapges.skeleton import UPPER_BODY, pose_to_motion

    refuse_overwrite(out, force)
    if fps is not None and fps <= 0:
        raise UserError(f"--fps must be positive, got {fps}")
    require_file(src, "BVH file")  # before the default skeleton's checkpoint loads
    skel = _target_skeleton(target)
    r = retarget_bvh(src, skel, joint_map, fps=fps)
    write_bvh(out, skel, pose_to_motion(skel, r.pose), r.fps)
    missing = [n for n, m in zip(UPPER_BODY, r.mask) if not m]
    typer.echo(
        f"{src.name} → {out}: {r.n_frames} frames at {r.fps:g} fps, joint map {r.map_name!r}, "
        f"{int(r.mask.sum())}/{len(UPPER_BODY)} joints" + (f" (at rest: {', '.join(missing)})" if missing else "")
    )


CACHE = typer.Argument(help="A cache folder made by `facecapges prepare`.")
CLIP = typer.Option("--clip", help="Clip name, e.g. 2_scott_0_1_1.")
EXPORT_OUT = typer.Option("--out", help="BVH file to write.")


def export(
    cache: Annotated[Path, CACHE],
    clip: Annotated[str, CLIP],
    out: Annotated[Path, EXPORT_OUT],
    force: Annotated[bool, FORCE_OUT] = False,
) -> None:
    """Write a cached clip's motion as BVH on the full BEAT hierarchy (other joints at rest).

    A clip retargeted from another skeleton gives its BEAT pose; joints the source
    lacks hold the cache's mean rotation."""
    from facecapges.data.cache import Cache
    from facecapges.errors import check_output_file
    from facecapges.io.bvh import write_bvh
    from facecapges.skeleton import pose_to_motion

    check_output_file(out, force)
    c = Cache(cache)
    arrays = c.load(clip)
    skel = c.skeleton(clip)
    motion = pose_to_motion(skel, arrays["pose"])
    write_bvh(out, skel, motion, c.fps)
    typer.echo(f"{clip}: {len(motion)} frames at {c.fps:g} fps → {out}")


def register(app: typer.Typer) -> None:
    """Add the data commands to ``app``."""
    app.command()(prepare)
    app.command()(retarget)
    app.command()(export)
