"""Commands of the evaluation area: ``fgd-train``, ``eval`` and ``ablate``.

``facecapges fgd-train`` trains the per-speaker FGD autoencoder (one per region) on a
cache's clips (or on BVH files) and writes it into a directory or next to a gesture
checkpoint (:func:`facecapges.evaluation.fgd.fgd_paths`).

``facecapges eval`` runs a checkpoint over held-out clips of a cache frame by frame
(the same streaming path as live use, cold start at the first held-out frame) and
writes the thesis's metrics for the model and the reference rows, in both regions,
with plots and a side-by-side video (see :mod:`facecapges.evaluation.run`).

``facecapges ablate`` trains the ablation variants of thesis 5.7 (full, without head
pose, offline decoding) and the CaMN baseline of 5.2.1 with one recipe and evaluates them on the held-out frames
into a Table 5.3 report (see :mod:`facecapges.evaluation.ablate`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import CACHE, OFFSETS, QUIET, QUIET_BAR
from facecapges.errors import UserError
from facecapges.evaluation.options import AblateOptions, EvalOptions, FgdTrainOptions


def _parse_regions(text: str) -> tuple[str, ...]:
    from facecapges.evaluation.regions import REGIONS

    regions = tuple(r.strip() for r in text.split(",") if r.strip())
    bad = [r for r in regions if r not in REGIONS]
    if bad or not regions:
        raise UserError(f"--regions must be a comma-separated subset of {', '.join(REGIONS)}, got {text!r}")
    return regions


FGD_SPEAKER = typer.Option("--speaker", help="BEAT speaker id (one FGD autoencoder per speaker).")
FGD_SPLIT = typer.Option("--split", help="Cache clips to train on: train, val, test or all.")
FGD_HOLDOUT = typer.Option(
    "--holdout-from", help="Use only frames before this frame of every clip (the rest is held out for evaluation)."
)
FGD_HOLDOUT_TAIL = typer.Option(
    "--holdout-tail",
    help="Use only frames before each cached clip's own hold-out (its holdout_from: the last 20 % stays unseen).",
)
FGD_BVH = typer.Option(
    "--bvh", help="BEAT BVH file(s) to train on instead of a cache (repeat the option for several files)."
)
FGD_OUT = typer.Option("--out", help="Directory to write fgd_autoencoder.safetensors/.json into.")
FGD_CHECKPOINT = typer.Option(
    "--checkpoint",
    help="Gesture checkpoint to store the autoencoder next to (in the folder NAME.fgd/), when --out is not given.",
)
FGD_EPOCHS = typer.Option("--epochs", help="Training epochs.")
BATCH_SIZE = typer.Option("--batch-size", help="Batch size B; the learning rate scales with it (1.2e-4 · B/128).")
MOMENTUM = typer.Option("--momentum", help="SGD momentum (0 = plain SGD).")
REGIONS = typer.Option("--regions", help="Regions to train an autoencoder for.")
FGD_SEED = typer.Option("--seed", help="Random seed.")
FGD_FORCE = typer.Option("--force", help="Overwrite an existing FGD autoencoder.")


def fgd_train(
    cache: Annotated[Path | None, CACHE] = FgdTrainOptions.cache,
    speaker: Annotated[int, FGD_SPEAKER] = FgdTrainOptions.speaker,
    split: Annotated[str, FGD_SPLIT] = FgdTrainOptions.split,
    holdout_from: Annotated[int | None, FGD_HOLDOUT] = FgdTrainOptions.holdout_from,
    holdout_tail: Annotated[bool, FGD_HOLDOUT_TAIL] = FgdTrainOptions.holdout_tail,
    bvh: Annotated[list[Path] | None, FGD_BVH] = None,
    out: Annotated[Path | None, FGD_OUT] = FgdTrainOptions.out,
    checkpoint: Annotated[Path | None, FGD_CHECKPOINT] = FgdTrainOptions.checkpoint,
    epochs: Annotated[int, FGD_EPOCHS] = FgdTrainOptions.epochs,
    batch_size: Annotated[int, BATCH_SIZE] = FgdTrainOptions.batch_size,
    momentum: Annotated[float, MOMENTUM] = FgdTrainOptions.momentum,
    regions: Annotated[str, REGIONS] = FgdTrainOptions.regions,
    seed: Annotated[int, FGD_SEED] = FgdTrainOptions.seed,
    force: Annotated[bool, FGD_FORCE] = FgdTrainOptions.force,
    quiet: Annotated[bool, QUIET_BAR] = FgdTrainOptions.quiet,
) -> None:
    """Train the skeleton-aware FGD autoencoder on a speaker's real motion (what `eval` measures FGD with)."""
    from facecapges.errors import refuse_overwrite, require_file

    if (cache is None) == (not bvh):
        raise UserError("give either --cache (with --speaker) or --bvh FILE, not both or neither")
    if out is None and checkpoint is None:
        raise UserError("give --out DIR or --checkpoint CKPT to say where the autoencoder goes")
    if checkpoint is not None and out is None and not checkpoint.is_file():
        raise UserError(f"{checkpoint}: checkpoint not found")
    if epochs < 1 or batch_size < 1:
        raise UserError("--epochs and --batch-size must be at least 1")
    if cache is not None:  # the cache and the speaker's clips before torch loads
        from facecapges.data.cache import Cache

        Cache(cache).select(speaker, split)
    for b in bvh or []:
        require_file(b, "BVH")
    from facecapges.evaluation.fgd import FGDConfig, fgd_paths, save_fgd, train_fgd
    from facecapges.evaluation.run import load_real_clips

    location = out if out is not None else checkpoint
    assert location is not None  # checked above
    for p in fgd_paths(location):
        refuse_overwrite(p, force)
    clips, source = load_real_clips(
        cache=cache, speaker=speaker, split=split, bvh=bvh, before_frame=holdout_from, own_holdout=holdout_tail
    )
    cfg = FGDConfig(epochs=epochs, batch_size=batch_size, momentum=momentum, seed=seed)
    n_frames = sum(len(c) for c in clips)
    typer.echo(
        f"FGD autoencoder on {len(clips)} clip(s), {n_frames} frames from {source}; "
        f"{epochs} epochs, B={batch_size}, lr={cfg.lr:.3g}"
    )
    try:
        ev = train_fgd(clips, cfg, regions=_parse_regions(regions), progress=not quiet)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    w, j = save_fgd(ev, location)
    last = ", ".join(f"{r} {v[-1]:.4f}" for r, v in ev.history.loss.items())
    typer.echo(f"{ev.history.n_windows} windows; final loss {last}\nwrote {w} and {j}")


EVAL_OUT = typer.Option("--out", help="Output folder: metrics.json, metrics.md, PNG plots, MP4.")
EVAL_CHECKPOINT = typer.Option("--checkpoint", help="Gesture checkpoint (default: the installed default style).")
EVAL_STYLE = typer.Option("--style", help="Installed style name instead of --checkpoint.")
EVAL_SPEAKER = typer.Option("--speaker", help="Speaker to evaluate (default: the checkpoint's).")
EVAL_SPLIT = typer.Option("--split", help="Clips to evaluate when --holdout-from is not given.")
EVAL_HOLDOUT = typer.Option(
    "--holdout-from",
    help="Evaluate frames from this frame on of every clip of the speaker; earlier frames are the real pool.",
)
EVAL_AUDIO = typer.Option(
    "--audio", help="Extra unseen speech (no motion): BeatAlign, L1DIV and FGD against the speaker's real motion."
)
EVAL_FGD = typer.Option(
    "--fgd", help="FGD autoencoder (directory or checkpoint it sits next to; default: next to the checkpoint)."
)
EVAL_VIDEO = typer.Option("--video/--no-video", help="Write real_vs_generated.mp4.")
EVAL_SEED = typer.Option("--seed", help="Seed for the random real segment baseline and the sample starts.")
EVAL_SAMPLES = typer.Option(
    "--samples",
    help="Model runs per clip (different cold-start histories) for the "
    "diversity across samples (L1DIV); metrics average over them.",
)
EVAL_FORCE = typer.Option("--force", help="Write into an OUT folder that already has metrics.")


def eval_cmd(
    cache: Annotated[Path, CACHE],
    out: Annotated[Path, EVAL_OUT],
    checkpoint: Annotated[Path | None, EVAL_CHECKPOINT] = EvalOptions.checkpoint,
    style: Annotated[str | None, EVAL_STYLE] = EvalOptions.style,
    speaker: Annotated[int | None, EVAL_SPEAKER] = EvalOptions.speaker,
    split: Annotated[str, EVAL_SPLIT] = EvalOptions.split,
    holdout_from: Annotated[int | None, EVAL_HOLDOUT] = EvalOptions.holdout_from,
    audio: Annotated[list[Path] | None, EVAL_AUDIO] = None,
    fgd: Annotated[Path | None, EVAL_FGD] = EvalOptions.fgd,
    offsets: Annotated[str, OFFSETS] = EvalOptions.offsets,
    video: Annotated[bool, EVAL_VIDEO] = EvalOptions.video,
    seed: Annotated[int, EVAL_SEED] = EvalOptions.seed,
    samples: Annotated[int, EVAL_SAMPLES] = EvalOptions.samples,
    force: Annotated[bool, EVAL_FORCE] = EvalOptions.force,
    quiet: Annotated[bool, QUIET] = EvalOptions.quiet,
) -> None:
    """Evaluate a checkpoint on held-out motion: FGD, SRGR, BeatAlign, L1DIV, with and without the head."""
    options = EvalOptions(**{**locals(), "audio": list(audio or [])})  # before any other name is bound here
    from facecapges.evaluation.run import run_eval

    run_eval(options, say=typer.echo)


ABLATE_OUT = typer.Option("--out", help="Output folder: ablation.md, ablation.json, runs/<variant>/.")
ABLATE_SPEAKER = typer.Option("--speaker", help="BEAT speaker id to train and evaluate.")
CONFIG = typer.Option(
    "--config",
    help="Base YAML/JSON recipe with 'model:'/'train:' sections "
    "(default: configs/demo-beat2-scott.yaml, the shipped model's recipe).",
)
ABLATE_EPOCHS = typer.Option(
    "--epochs",
    help="Epochs for every variant (default: the config's). Not the FGD autoencoder's: that is --fgd-epochs "
    "(400) when none is found; pass --fgd to use an existing one.",
)
ABLATE_SPLIT = typer.Option("--split", help="Clips to train on (default: all with a hold-out frame, else train).")
ABLATE_HOLDOUT = typer.Option(
    "--holdout-from",
    help="Hold out frames >= this of every clip (default: the config's holdout_from); they are evaluated.",
)
VARIANTS = typer.Option(
    "--variants", help="Comma-separated variants: full, no_head, offline, camn (the CaMN baseline)."
)
REUSE_DEFAULT = typer.Option(
    "--reuse-default/--no-reuse-default",
    help="Use the shipped default checkpoint as 'full' when its stored recipe and data match.",
)
GIVEN = typer.Option(
    "--given",
    help="VARIANT=CHECKPOINT[,…]: take these rows from existing checkpoints as they are (a file, or an "
    "installed style for full/no_head), whatever their recipe, e.g. full=beat2-scott-demo.",
)
RETRAIN = typer.Option("--retrain", help="Train every variant even if OUT/runs holds a finished model of this recipe.")
ABLATE_FGD = typer.Option(
    "--fgd",
    help="FGD autoencoder (directory or checkpoint it sits next to); default: the shipped one when 'full' "
    "is the shipped checkpoint, else trained into OUT/fgd.",
)
FGD_EPOCHS_ABLATE = typer.Option("--fgd-epochs", help="Epochs when an FGD autoencoder must be trained.")
ABLATE_SAMPLES = typer.Option("--samples", help="Runs per variant and clip (different start histories).")
ABLATE_SEED = typer.Option("--seed", help="Seed of the random real segment and the start histories.")
ABLATE_FORCE = typer.Option("--force", help="Write into an OUT folder that already has a table.")


def ablate_cmd(
    cache: Annotated[Path, CACHE],
    out: Annotated[Path, ABLATE_OUT],
    speaker: Annotated[int, ABLATE_SPEAKER] = AblateOptions.speaker,
    config: Annotated[Path | None, CONFIG] = AblateOptions.config,
    epochs: Annotated[int | None, ABLATE_EPOCHS] = AblateOptions.epochs,
    split: Annotated[str | None, ABLATE_SPLIT] = AblateOptions.split,
    holdout_from: Annotated[int | None, ABLATE_HOLDOUT] = AblateOptions.holdout_from,
    variants: Annotated[str, VARIANTS] = AblateOptions.variants,
    reuse_default: Annotated[bool, REUSE_DEFAULT] = AblateOptions.reuse_default,
    given: Annotated[str | None, GIVEN] = AblateOptions.given,
    retrain: Annotated[bool, RETRAIN] = AblateOptions.retrain,
    fgd: Annotated[Path | None, ABLATE_FGD] = AblateOptions.fgd,
    fgd_epochs: Annotated[int, FGD_EPOCHS_ABLATE] = AblateOptions.fgd_epochs,
    samples: Annotated[int, ABLATE_SAMPLES] = AblateOptions.samples,
    offsets: Annotated[str, OFFSETS] = AblateOptions.offsets,
    seed: Annotated[int, ABLATE_SEED] = AblateOptions.seed,
    force: Annotated[bool, ABLATE_FORCE] = AblateOptions.force,
    quiet: Annotated[bool, QUIET] = AblateOptions.quiet,
) -> None:
    """Ablation study: train the model's variants with one budget, evaluate them side by side."""
    options = AblateOptions(**locals())  # before any other name is bound here
    import sys

    from facecapges.evaluation.ablate import run_ablation

    run_ablation(options, say=typer.echo, command="facecapges " + " ".join(sys.argv[1:]))


def register(app: typer.Typer) -> None:
    app.command("fgd-train")(fgd_train)
    app.command("eval")(eval_cmd)
    app.command("ablate")(ablate_cmd)
