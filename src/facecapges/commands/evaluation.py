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

import typer

from facecapges.errors import UserError
from facecapges.evaluation.options import AblateOptions, EvalOptions, FgdTrainOptions


def _parse_regions(text: str) -> tuple[str, ...]:
    from facecapges.evaluation.regions import REGIONS

    regions = tuple(r.strip() for r in text.split(",") if r.strip())
    bad = [r for r in regions if r not in REGIONS]
    if bad or not regions:
        raise UserError(f"--regions must be a comma-separated subset of {', '.join(REGIONS)}, got {text!r}")
    return regions


def _parse_offsets(text: str) -> list[float]:
    """``"2:60:2"`` (start:stop:step, stop included) or ``"2,5,9"`` → offsets in seconds."""
    try:
        if ":" in text:
            a, b, c = (float(x) for x in text.split(":"))
            if c <= 0 or b < a:
                raise ValueError
            n = int((b - a) // c) + 1
            return [a + i * c for i in range(n)]
        out = [float(x) for x in text.split(",") if x.strip()]
        if not out:
            raise ValueError
        return out
    except ValueError:
        raise UserError(f"--offsets must be START:STOP:STEP or a comma list of seconds, got {text!r}") from None


def _parse_given(text: str | None) -> dict[str, str]:
    """``"full=beat2-scott-demo,camn=run/model.safetensors"`` → {variant: checkpoint}."""
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        name, sep, ref = item.partition("=")
        if not sep or not name.strip() or not ref.strip():
            raise UserError(f"--given must be VARIANT=CHECKPOINT[,VARIANT=CHECKPOINT…], got {text!r}")
        out[name.strip()] = ref.strip()
    return out


def fgd_train(
    cache: Path | None = typer.Option(FgdTrainOptions.cache, help="A cache written by `facecapges prepare`."),
    speaker: int = typer.Option(FgdTrainOptions.speaker, help="BEAT speaker id (one FGD autoencoder per speaker)."),
    split: str = typer.Option(FgdTrainOptions.split, help="Cache clips to train on: train, val, test or all."),
    holdout_from: int | None = typer.Option(
        FgdTrainOptions.holdout_from,
        help="Use only frames before this frame of every clip (the rest is held out for evaluation).",
    ),
    bvh: list[Path] | None = typer.Option(
        None, help="BEAT BVH file(s) to train on instead of a cache (repeat the option for several files)."
    ),
    out: Path | None = typer.Option(
        FgdTrainOptions.out, help="Directory to write fgd_autoencoder.safetensors/.json into."
    ),
    checkpoint: Path | None = typer.Option(
        FgdTrainOptions.checkpoint,
        help="Gesture checkpoint to store the autoencoder next to (in the folder NAME.fgd/), when --out is not given.",
    ),
    epochs: int = typer.Option(FgdTrainOptions.epochs, help="Training epochs."),
    batch_size: int = typer.Option(
        FgdTrainOptions.batch_size, help="Batch size B; the learning rate scales with it (1.2e-4 · B/128)."
    ),
    momentum: float = typer.Option(FgdTrainOptions.momentum, help="SGD momentum (0 = plain SGD)."),
    regions: str = typer.Option(FgdTrainOptions.regions, help="Regions to train an autoencoder for."),
    seed: int = typer.Option(FgdTrainOptions.seed, help="Random seed."),
    force: bool = typer.Option(FgdTrainOptions.force, "--force", help="Overwrite an existing FGD autoencoder."),
    quiet: bool = typer.Option(FgdTrainOptions.quiet, "--quiet", help="No progress bar."),
) -> None:
    """Train the skeleton-aware FGD autoencoder on a speaker's real motion (what `eval` measures FGD with)."""
    from facecapges.errors import refuse_overwrite
    from facecapges.evaluation.fgd import FGDConfig, fgd_paths, save_fgd, train_fgd
    from facecapges.evaluation.run import load_real_clips

    if (cache is None) == (not bvh):
        raise UserError("give either --cache (with --speaker) or --bvh FILE, not both or neither")
    if out is None and checkpoint is None:
        raise UserError("give --out DIR or --checkpoint CKPT to say where the autoencoder goes")
    if checkpoint is not None and out is None and not checkpoint.is_file():
        raise UserError(f"{checkpoint}: checkpoint not found")
    if epochs < 1 or batch_size < 1:
        raise UserError("--epochs and --batch-size must be at least 1")
    location = out if out is not None else checkpoint
    assert location is not None  # checked above
    for p in fgd_paths(location):
        refuse_overwrite(p, force)
    clips, source = load_real_clips(cache=cache, speaker=speaker, split=split, bvh=bvh, before_frame=holdout_from)
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


def eval_cmd(
    cache: Path = typer.Option(..., help="A cache written by `facecapges prepare`."),
    out: Path = typer.Option(..., help="Output folder: metrics.json, metrics.md, PNG plots, MP4."),
    checkpoint: Path | None = typer.Option(
        EvalOptions.checkpoint, help="Gesture checkpoint (default: the installed default style)."
    ),
    style: str | None = typer.Option(EvalOptions.style, help="Installed style name instead of --checkpoint."),
    speaker: int | None = typer.Option(EvalOptions.speaker, help="Speaker to evaluate (default: the checkpoint's)."),
    split: str = typer.Option(EvalOptions.split, help="Clips to evaluate when --holdout-from is not given."),
    holdout_from: int | None = typer.Option(
        EvalOptions.holdout_from,
        help="Evaluate frames from this frame on of every clip of the speaker; earlier frames are the real pool.",
    ),
    audio: list[Path] | None = typer.Option(
        None, help="Extra unseen speech (no motion): BeatAlign, L1DIV and FGD against the speaker's real motion."
    ),
    fgd: Path | None = typer.Option(
        EvalOptions.fgd,
        help="FGD autoencoder (directory or checkpoint it sits next to; default: next to the checkpoint).",
    ),
    offsets: str = typer.Option(
        EvalOptions.offsets, help="BeatAlign control: audio shifts in s (START:STOP:STEP or list)."
    ),
    video: bool = typer.Option(EvalOptions.video, "--video/--no-video", help="Write real_vs_generated.mp4."),
    seed: int = typer.Option(EvalOptions.seed, help="Seed for the random real segment baseline and the sample starts."),
    samples: int = typer.Option(
        EvalOptions.samples,
        help="Model runs per clip (different cold-start histories) for the "
        "diversity across samples (L1DIV); metrics average over them.",
    ),
    force: bool = typer.Option(EvalOptions.force, "--force", help="Write into an OUT folder that already has metrics."),
    quiet: bool = typer.Option(EvalOptions.quiet, "--quiet", help="No progress bars."),
) -> None:
    """Evaluate a checkpoint on held-out motion: FGD, SRGR, BeatAlign, L1DIV, with and without the head."""
    from facecapges.evaluation.run import run_eval

    run_eval(
        cache=cache,
        out=out,
        checkpoint=checkpoint,
        style=style,
        speaker=speaker,
        split=split,
        holdout_from=holdout_from,
        extra_audio=list(audio or []),
        fgd_location=fgd,
        offsets_s=_parse_offsets(offsets),
        video=video,
        seed=seed,
        samples=samples,
        progress=not quiet,
        force=force,
        say=typer.echo,
    )


def ablate_cmd(
    cache: Path = typer.Option(..., help="A cache written by `facecapges prepare`."),
    out: Path = typer.Option(..., help="Output folder: ablation.md, ablation.json, runs/<variant>/."),
    speaker: int = typer.Option(AblateOptions.speaker, help="BEAT speaker id to train and evaluate."),
    config: Path | None = typer.Option(
        AblateOptions.config,
        help="Base YAML/JSON recipe with 'model:'/'train:' sections "
        "(default: configs/demo-beat2-scott.yaml, the shipped "
        "model's recipe).",
    ),
    epochs: int | None = typer.Option(
        AblateOptions.epochs,
        help="Epochs for every variant (default: the config's). Not the "
        "FGD autoencoder's: that is --fgd-epochs (400) when none "
        "is found; pass --fgd to use an existing one.",
    ),
    split: str | None = typer.Option(
        AblateOptions.split, help="Clips to train on (default: all with a hold-out frame, else train)."
    ),
    holdout_from: int | None = typer.Option(
        AblateOptions.holdout_from,
        help="Hold out frames >= this of every clip (default: the config's holdout_from); they are evaluated.",
    ),
    variants: str = typer.Option(
        AblateOptions.variants,
        help="Comma-separated variants: full, no_head, offline, camn (the CaMN baseline).",
    ),
    reuse_default: bool = typer.Option(
        AblateOptions.reuse_default,
        "--reuse-default/--no-reuse-default",
        help="Use the shipped default checkpoint as 'full' when its stored recipe and data match.",
    ),
    given: str | None = typer.Option(
        AblateOptions.given,
        "--given",
        help="VARIANT=CHECKPOINT[,…]: take these rows from "
        "existing checkpoints as they are (a file, or an "
        "installed style for full/no_head), whatever "
        "their recipe, e.g. full=beat2-scott-demo.",
    ),
    retrain: bool = typer.Option(
        AblateOptions.retrain,
        "--retrain",
        help="Train every variant even if OUT/runs holds a finished model of this recipe.",
    ),
    fgd: Path | None = typer.Option(
        AblateOptions.fgd,
        help="FGD autoencoder (directory or checkpoint it sits next to); "
        "default: the shipped one when 'full' is the shipped "
        "checkpoint, else trained into OUT/fgd.",
    ),
    fgd_epochs: int = typer.Option(AblateOptions.fgd_epochs, help="Epochs when an FGD autoencoder must be trained."),
    samples: int = typer.Option(AblateOptions.samples, help="Runs per variant and clip (different start histories)."),
    offsets: str = typer.Option(
        AblateOptions.offsets, help="BeatAlign control: audio shifts in s (START:STOP:STEP or list)."
    ),
    seed: int = typer.Option(AblateOptions.seed, help="Seed of the random real segment and the start histories."),
    force: bool = typer.Option(
        AblateOptions.force, "--force", help="Write into an OUT folder that already has a table."
    ),
    quiet: bool = typer.Option(AblateOptions.quiet, "--quiet", help="No progress bars."),
) -> None:
    """Ablation study: train the model's variants with one budget, evaluate them side by side."""
    import sys

    from facecapges.evaluation.ablate import run_ablation

    run_ablation(
        cache=cache,
        out=out,
        speaker=speaker,
        config=config,
        epochs=epochs,
        split=split,
        holdout_from=holdout_from,
        variants=tuple(v.strip() for v in variants.split(",") if v.strip()),
        reuse_default=reuse_default,
        retrain=retrain,
        fgd_location=fgd,
        fgd_epochs=fgd_epochs,
        samples=samples,
        seed=seed,
        offsets_s=_parse_offsets(offsets),
        progress=not quiet,
        say=typer.echo,
        given=_parse_given(given),
        command="facecapges " + " ".join(sys.argv[1:]),
        force=force,
    )


def register(app: typer.Typer) -> None:
    app.command("fgd-train")(fgd_train)
    app.command("eval")(eval_cmd)
    app.command("ablate")(ablate_cmd)
