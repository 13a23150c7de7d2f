"""``facecapges prepare`` and ``facecapges export``: BEAT files → cache → BVH."""

from __future__ import annotations

from pathlib import Path

import typer

from facecapges.errors import UserError


def parse_speakers(text: str) -> list[int] | None:
    """``"2,4,6,8"`` → [2, 4, 6, 8]; empty → None (all speakers)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    try:
        return [int(p) for p in parts] or None
    except ValueError:
        raise UserError(f"--speakers must be comma-separated speaker ids like 2,4,6,8, got {text!r}") from None


def register(app: typer.Typer) -> None:
    """Add the data commands to ``app``."""

    @app.command()
    def prepare(
        beat_root: Path = typer.Argument(..., help="Folder with BEAT files ({spk}_{name}_{type}_{start}_{end}"
                                                   ".bvh/.wav/.json/.txt/.csv), searched recursively."),
        out: Path = typer.Option(..., "--out", help="Cache folder to create."),
        speakers: str = typer.Option("", help="Comma-separated speaker ids to keep, e.g. 2,4,6,8 (default: all)."),
        fps: float = typer.Option(15.0, help="Frame rate of the cache (BEAT rule: 120 fps keeps every 8th frame)."),
        force: bool = typer.Option(False, "--force", help="Replace an existing cache at --out."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Build a training cache (pose, head, face, semantic, emotion, audio, splits, stats) from BEAT files."""
        from rich.console import Console

        from facecapges.data.prepare import prepare as run_prepare
        from facecapges.data.prepare import summary_table
        from facecapges.errors import check_output_dir

        check_output_dir(out)  # a file in the way or a folder that cannot be written: now, not after the work
        index = run_prepare(beat_root, out, speakers=parse_speakers(speakers), fps=fps, force=force,
                            progress=not quiet)
        console = Console()
        for w in index.get("warnings", []):
            console.print(f"[yellow]warning:[/yellow] {w}")
        console.print(summary_table(index))
        n = len(index["clips"])
        frames = sum(c["n_frames"] for c in index["clips"])
        audio_only = sum(1 for s in index["skipped"] if s["reason"] == "audio only")
        console.print(f"{n} clip{'s' if n != 1 else ''}, {frames} frames, {frames / index['fps']:.1f} s"
                      f"{f', {audio_only} audio only' if audio_only else ''} → {out}")

    @app.command()
    def export(
        cache: Path = typer.Argument(..., help="A cache folder made by `facecapges prepare`."),
        clip: str = typer.Option(..., "--clip", help="Clip name, e.g. 2_scott_0_1_1."),
        out: Path = typer.Option(..., "--out", help="BVH file to write."),
        force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
    ) -> None:
        """Write a cached clip's motion as BVH on the full BEAT hierarchy (other joints at rest)."""
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
