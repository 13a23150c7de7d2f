"""Commands of the user-study area: ``study create``, ``study serve``, ``study analyze``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.study.options import StudyAnalyzeOptions, StudyCreateOptions, StudyServeOptions

CLIPS = typer.Option(
    "--clips",
    help="CLIPS.yaml: the clips (speech, face track) and one BVH per system and clip (format: facecapges.study.clips).",
)
CREATE_OUT = typer.Option("--out", help="Study folder to write.")
PARTICIPANTS = typer.Option(
    "--participants",
    help="Number of participant plans (default: one per row of the balanced Latin square: N clips, 2N for odd N).",
)
SEED = typer.Option("--seed", help="Seed of the clip assignment and the screen positions.")
CREATE_FORCE = typer.Option("--force", help="Overwrite an existing study (never one with answers).")
AVATAR = typer.Option(
    "--avatar",
    help="Show this avatar: a VRM 0.x/1.0 or a humanoid GLB (default: ours, built from the first BVH).",
)


def create_cmd(
    clips: Annotated[Path, CLIPS],
    out: Annotated[Path, CREATE_OUT],
    participants: Annotated[int | None, PARTICIPANTS] = StudyCreateOptions.participants,
    seed: Annotated[int, SEED] = StudyCreateOptions.seed,
    force: Annotated[bool, CREATE_FORCE] = StudyCreateOptions.force,
    avatar: Annotated[Path | None, AVATAR] = StudyCreateOptions.avatar,
) -> None:
    """Validate the clips, build the avatar, precompute every pose track and write the participant plans."""
    from facecapges.study.build import create_study

    s = create_study(clips, out, participants, seed, force, avatar=avatar)
    b = s["balance"]
    typer.echo(
        f"{out}: {s['clips']} clips × {s['systems']} systems at {s['fps']:g} fps, "
        f"{s['participants']} participants (ids P01…)"
    )
    notes = []
    if b["serial_position_spread"] or b["carry_over_spread"]:
        notes.append(f"clip order is exactly balanced only for a multiple of {b['sequences']} participants")
    if b["position_spread"]:
        notes.append(
            f"screen positions are exactly balanced only when participants × clips is a multiple of {s['systems']}"
        )
    typer.echo(
        "balance: " + ("; ".join(notes) if notes else "clip order, carry-over and screen positions exactly balanced")
    )
    typer.echo(f"invitation links (one per participant, keep them private): {out / 'invitations.txt'}")
    typer.echo(f"next: facecapges study serve {out}")


SERVE_STUDY_DIR = typer.Argument(help="Study folder made by 'facecapges study create'.")
HOST = typer.Option("--host", help="Address to listen on (0.0.0.0: every interface).")
PORT = typer.Option("--port", help="TCP port.")
LANGUAGE = typer.Option(
    "--language", help="Language the page starts in: en (English) or zh (Chinese); participants can switch."
)


def serve_cmd(
    study_dir: Annotated[Path, SERVE_STUDY_DIR],
    host: Annotated[str, HOST] = StudyServeOptions.host,
    port: Annotated[int, PORT] = StudyServeOptions.port,
    language: Annotated[str, LANGUAGE] = StudyServeOptions.language,
) -> None:
    """Serve the study page; answers go to STUDY_DIR/responses/ as they are given. Ctrl-C stops.

    Each participant opens his own invitation link (listed in STUDY_DIR/invitations.txt);
    the link's token is his only credential.
    """
    from facecapges.study.server import serve_study

    serve_study(study_dir, host, port, language, say=typer.echo)


ANALYZE_STUDY_DIR = typer.Argument(help="Study folder with answers in responses/.")
ANALYZE_OUT = typer.Option("--out", help="Folder for results.json, results.md and the PNG plots.")
ONLY = typer.Option("--only", help="Comma-separated participant ids to analyse (default: all).")
ANALYZE_FORCE = typer.Option("--force", help="Overwrite results already in --out.")


def analyze_cmd(
    study_dir: Annotated[Path, ANALYZE_STUDY_DIR],
    out: Annotated[Path, ANALYZE_OUT],
    only: Annotated[str, ONLY] = StudyAnalyzeOptions.only,
    force: Annotated[bool, ANALYZE_FORCE] = StudyAnalyzeOptions.force,
) -> None:
    """Mean ranks with 95 % intervals, Friedman test, Holm-corrected Wilcoxon pairs, bar plots."""
    from facecapges.errors import UserError, echo_warning, refuse_overwrite
    from facecapges.study.analyze import analyze_study, collect_answers
    from facecapges.study.build import open_study

    st = open_study(study_dir)
    left_out: list[str] = []
    answers = collect_answers(st, left_out)
    if left_out:
        echo_warning(
            f"warning: left out {len(left_out)} answer(s) not given with the participant's invitation "
            f"token ({', '.join(left_out[:5])}{', …' if len(left_out) > 5 else ''})"
        )
    if not answers:
        raise UserError(f"{study_dir}: no answers yet in responses/ (that were given with an invitation token)")
    chosen = None
    if only.strip():
        chosen = [p.strip().upper() for p in only.split(",") if p.strip()]
        known = {p.id for p in st.plan.participants}
        bad = [p for p in chosen if p not in known]
        if bad:
            raise UserError(f"--only: unknown participant id(s) {bad}; the study has {sorted(known)}")
        if not any(a["participant"] in chosen for a in answers):
            raise UserError(f"--only: participants {chosen} have not answered yet")
    for name in ("results.json", "results.md", "mean_rank.png", "rank_shares.png"):
        refuse_overwrite(out / name, force)
    r = analyze_study(st, out, chosen)
    typer.echo((out / "results.md").read_text(encoding="utf-8"))
    typer.echo(f"written: {out / 'results.json'}, {out / 'results.md'}, " + ", ".join(r["plots"]))


def register(app: typer.Typer) -> None:
    study = typer.Typer(
        help="Blind side-by-side user study: K versions of each clip ranked on realism, synchrony and diversity.",
        no_args_is_help=True,
    )
    app.add_typer(study, name="study")
    study.command("create")(create_cmd)
    study.command("serve")(serve_cmd)
    study.command("analyze")(analyze_cmd)
