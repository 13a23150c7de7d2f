"""``facecapges styles build``: a matching style from paired takes, in minutes on a CPU.

Steps: read and check every ``--take MOTION WAV`` (BEAT BVH at any rate, BEAT2 ``.npz``, or a
BVH of another skeleton — ZEGGS, a user's mocap — retargeted onto the BEAT skeleton), build the
database from each take's training frames and their mirror images, train the speech predictor
on the same frames, write the style (:mod:`facecapges.matching.style`) and its model card
``NAME.md`` beside it. Frames from ``train_until`` (the last 20 % of every take) are never read
for any of it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.errors import UserError, file_error
from facecapges.matching.database import build_database
from facecapges.matching.matcher import MatchingConfig
from facecapges.matching.style import save_matching_style
from facecapges.matching.takes import Take, load_take
from facecapges.skeleton import Skeleton

BEAT_ATTRIBUTION = "BEAT / BEAT2 (Liu et al., ECCV 2022; EMAGE, CVPR 2024), CC BY-NC 4.0"
ZEGGS_ATTRIBUTION = "ZEGGS (Ubisoft La Forge ZeroEGGS), CC BY-NC-ND 4.0: built on this machine, never distribute"
MIN_TRAIN_S = 10.0
MAX_FILE_NAME_BYTES = 200  # --out's file name: NAME.safetensors.part must fit the usual 255-byte limit


_CC_TERMS = {"Attribution": "BY", "NonCommercial": "NC", "NoDerivatives": "ND", "NoDerivs": "ND", "ShareAlike": "SA"}


def licence_file_terms(motion: Path) -> tuple[str, Path] | None:
    """(short licence, the file) of a Creative Commons licence text beside ``motion`` (``LICENSE*``, e.g.
    ZEGGS's ``LICENSE-ZEGGS.md``), read from its title: "Creative Commons Attribution-NonCommercial-
    NoDerivatives 4.0 International Public License" → "CC BY-NC-ND 4.0"; None when there is none."""
    folder = Path(motion).resolve().parent
    for f in sorted(folder.glob("LICEN[CS]E*")) + sorted(folder.glob("COPYING*")):
        if not f.is_file():
            continue
        try:
            head = f.read_text(encoding="utf-8", errors="replace")[:2000]
        except OSError:
            continue
        m = re.search(
            r"Creative Commons ((?:Attribution|NonCommercial|NoDerivatives|NoDerivs|ShareAlike|-)+) (\d\.\d)", head
        )
        if m:
            terms = [_CC_TERMS[t] for t in m.group(1).split("-") if t in _CC_TERMS]
            return f"CC {'-'.join(terms)} {m.group(2)}", f
    return None


def licence_of(take: Take) -> tuple[str, str]:
    """(licence, attribution) of a take, from its source: BEAT/BEAT2 names, a retarget map's licence (ZEGGS's
    skeleton), else a Creative Commons licence file beside the motion file (a ZEGGS take already retargeted
    onto the BEAT skeleton, next to LICENSE-ZEGGS.md); only without any of them the user's own."""
    from facecapges.data.beat import parse_clip_name

    if "ND" in take.licence:
        return take.licence, ZEGGS_ATTRIBUTION
    if take.licence or parse_clip_name(Path(take.source).stem) is not None:
        return take.licence or "CC BY-NC 4.0", BEAT_ATTRIBUTION
    found = licence_file_terms(Path(take.source))
    if found is not None:
        licence, f = found
        if "zeggs" in f.name.lower() or "ZEGGS" in f.read_text(encoding="utf-8", errors="replace")[:2000]:
            return licence, ZEGGS_ATTRIBUTION
        never = ": never distribute" if "ND" in licence else ""
        return licence, f"{Path(take.source).name}, {licence} ({f.name} beside it){never}"
    return "the user's own", "the user's own recordings"


def check_pairs(pairs: list[tuple[Path, Path]]) -> None:
    """Cheap checks of every ``--take MOTION WAV`` (kinds, files, the audio's header), before anything loads."""
    from facecapges.errors import require_file
    from facecapges.io.audio import check_audio

    if not pairs:
        raise UserError("give at least one --take MOTION WAV")
    for motion, wav in pairs:
        motion = Path(motion)
        if motion.suffix.lower() not in (".bvh", ".npz"):
            raise file_error(motion, "a --take's motion must be a .bvh or a BEAT2 .npz file")
        require_file(motion, "motion file")
        check_audio(wav)


def read_takes(
    pairs: list[tuple[Path, Path]],
    target: Skeleton | None = None,
    say=print,
    fallback_skeleton: Callable[[], Skeleton] | None = None,
) -> list[Take]:
    """Load every (motion, wav) pair; non-BEAT skeletons go onto ``target`` (default: the first take's BEAT
    skeleton, else ``fallback_skeleton()`` — the shelf gives the default style's)."""
    if not pairs:
        raise UserError("give at least one --take MOTION WAV")
    takes: list[Take] = []
    for motion, wav in pairs:
        motion, wav = Path(motion), Path(wav)
        if motion.suffix.lower() not in (".bvh", ".npz"):
            raise file_error(motion, "a --take's motion must be a .bvh or a BEAT2 .npz file")
        if target is None and motion.suffix.lower() == ".npz":
            target = _default_skeleton(takes, fallback_skeleton)
        try:
            take = load_take(motion, wav, target)
        except UserError as exc:
            if "no BEAT skeleton was given" not in str(exc):
                raise
            take = load_take(motion, wav, _default_skeleton(takes, fallback_skeleton))
        if take.train_until / timing.MODEL_FPS < MIN_TRAIN_S:
            raise file_error(motion, f"too short: a take needs {MIN_TRAIN_S / 0.8:.1f} s at least (its 80 % trains)")
        if target is None and not take.skeleton.missing():
            target = take.skeleton
        say(f"  {motion.name}: {take.n_frames / timing.MODEL_FPS:.1f} s, training frames [0, {take.train_until})")
        for note in take.notes:
            say(f"  warning: {note}")
        takes.append(take)
    skel = takes[0].skeleton
    if any(not t.skeleton.is_same_tree(skel) for t in takes):
        raise UserError("the takes are on different BEAT skeletons; give takes of one speaker's skeleton")
    return takes


def _speaker(takes: list[Take]) -> int | None:
    """The BEAT speaker id if every take is named as a BEAT/BEAT2 take of one speaker, else None."""
    from facecapges.data.beat import parse_clip_name

    ids = {getattr(parse_clip_name(Path(t.source).stem), "speaker", None) for t in takes}
    return ids.pop() if len(ids) == 1 else None


def _default_skeleton(takes: list[Take], fallback: Callable[[], Skeleton] | None) -> Skeleton:
    for t in takes:
        if not t.skeleton.missing():
            return t.skeleton
    if fallback is None:
        raise UserError("no take carries a BEAT skeleton and no fallback skeleton was given")
    return fallback()


def build_style(
    name: str,
    pairs: list[tuple[Path, Path]],
    dest: Path,
    fallback_skeleton: Callable[[], Skeleton],
    force: bool = False,
    progress: bool = True,
    seed: int = 0,
    config: MatchingConfig | None = None,
    target: Skeleton | None = None,
    say: Callable[[str], None] = print,
    predictor_steps: int | None = None,
    seen: dict[str, dict] | None = None,
) -> Path:
    """Build and write the matching style ``name`` to ``dest`` (the shelf chooses it:
    :func:`facecapges.styles.build_matching_style`); returns its path (module docs).

    ``seen``: for motion captured from a video (``styles build --video``), per motion file name how
    well it was seen (:func:`facecapges.capture.body.seen_report`); the card and meta carry it."""
    from dataclasses import replace

    check_pairs(pairs)  # every file before torch loads
    if Path(dest).suffix != ".safetensors":
        raise file_error(Path(dest), "a style file must end in .safetensors")
    from facecapges.matching.predictor import PredictorSettings
    from facecapges.matching.predictor_training import train_predictor

    settings = PredictorSettings()
    if predictor_steps is not None:
        if predictor_steps < 1:
            raise UserError(f"--steps must be at least 1, got {predictor_steps}")
        settings = replace(
            settings, steps=int(predictor_steps), eval_every=min(settings.eval_every, int(predictor_steps))
        )
    dest = Path(dest)
    if len(dest.name.encode()) > MAX_FILE_NAME_BYTES:
        raise file_error(
            dest, f"a file name of at most {MAX_FILE_NAME_BYTES} bytes, please (a style writes NAME.part first)"
        )
    card = dest.with_suffix(".md")
    for p in (dest, card):
        try:
            there = p.exists()
        except OSError as exc:  # a folder on the way that is a file, no permission to look …
            raise file_error(p, f"cannot be checked ({exc.strerror or exc})") from None
        if there and not force:
            raise file_error(p, "exists; pass --force to replace it")
    say(f"reading {len(pairs)} take(s)")
    takes = read_takes([(Path(m), Path(w)) for m, w in pairs], target, say, fallback_skeleton)
    say("building the database (training frames and their mirror images)")
    db = build_database(takes)
    say(f"  {len(db)} frames ({len(db) / timing.MODEL_FPS:.0f} s)")
    say(f"training the speech predictor (at most {settings.steps} steps; it stops when validation stops improving)")
    predictor = train_predictor(takes, seed=seed, progress=progress, settings=settings)
    licences = sorted({licence_of(t) for t in takes})
    meta = {
        "name": name,
        "speaker": _speaker(takes),
        "takes": [
            {
                "name": t.name,
                "source": Path(t.source).name,
                "frames_used": [0, t.train_until],
                "held_out": [t.train_until, t.n_frames],
                **({"captured_from": seen[Path(t.source).name]} if seen and Path(t.source).name in seen else {}),
            }
            for t in takes
        ],
        "licence": "; ".join(lic for lic, _ in licences),
        "attribution": "; ".join(att for _, att in licences),
        "predictor_training": predictor.config.get("training"),
    }
    path = save_matching_style(dest, db, config or MatchingConfig(), takes[0].skeleton, predictor, meta)
    card.write_text(model_card(name, meta, len(db), db.pause.mean()), encoding="utf-8")
    say(f"wrote {path} and {card.name}")
    return path


def _seen_section(takes: list[dict]) -> str:
    """The card's account of motion captured from video: where it came from and how well it was seen."""
    rows = [t for t in takes if t.get("captured_from")]
    if not rows:
        return ""
    from facecapges.capture.body_solve import ACCEL_LIMIT, FINGER_SIGMA, STYLE_SIGMA

    joints = list(rows[0]["captured_from"]["joint_confidence"])
    lines = [
        "",
        "## Motion captured from video",
        "",
        "The motion of these takes was captured from a video by `facecapges capture-body` (MediaPipe pose and",
        "hand landmarks → BEAT joints; see docs/capture-body.md for how close it comes to real motion capture),",
        f"smoothed over time for the database (rotations σ {STYLE_SIGMA:g} frame, fingers {FINGER_SIGMA:g}, each joint's",
        f'acceleration limited to {ACCEL_LIMIT:g} rad/s²: docs/capture-body.md, "A smoother capture for a style").',
        "Share of frames in which the person, each hand and both hands were found, and each joint's mean",
        "confidence (0–1; below 0.5 a joint eases to a relaxed rest pose):",
        "",
        "| take | video | frames | person | right hand | left hand | both hands | " + " | ".join(joints) + " |",
        "|---" * (7 + len(joints)) + "|",
    ]
    for t in rows:
        c = t["captured_from"]
        lines.append(
            f"| {t['name']} | {c['video']} | {c['frames']} | {c['person_found']:.0%} | {c['right_hand_found']:.0%} | "
            f"{c['left_hand_found']:.0%} | {c['both_hands_found']:.0%} | "
            + " | ".join(f"{c['joint_confidence'][j]:.2f}" for j in joints)
            + " |"
        )
    return "\n".join(lines) + "\n"


def model_card(name: str, meta: dict, n_rows: int, pause_share: float, figures: str = "") -> str:
    """The style's model card (markdown)."""
    rows = "\n".join(
        f"| {t['name']} | {t['source']} | {t['frames_used'][0]}–{t['frames_used'][1]} | "
        f"{t['held_out'][0]}–{t['held_out'][1]} |"
        for t in meta["takes"]
    )
    tr = meta.get("predictor_training") or {}
    return f"""# {name} — a motion-matching style

Engine: **matching** (facecapges.matching): replays the speaker's real motion (database of
{n_rows} frames = {n_rows / timing.MODEL_FPS:.0f} s at {timing.MODEL_FPS} fps, the takes' training frames and their mirror
images; {100 * pause_share:.0f} % pause frames), chosen each 100–200 ms and at speech onsets by the
speech predictor's expected wrist motion, blended by inertialization.

## Data

| take | file | frames used (15 fps) | held out (never used) |
|---|---|---|---|
{rows}

Licence: {meta["licence"]}. Attribution: {meta["attribution"]}.
{_seen_section(meta["takes"])}
## Speech predictor

Trained on the same training frames: {tr.get("steps", "?")} steps (best at {tr.get("best_step", "?")}),
validation loss with the head held still {np.round(tr.get("validation_loss_head_still", float("nan")), 4)}.
{figures}
"""
