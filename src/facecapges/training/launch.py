"""``facecapges train`` as a function: the run folder, the clips, the trainer — alone or under torchrun.

:func:`train_run` starts the process group (:func:`facecapges.training.distributed.init_distributed`),
lets rank 0 check and lock the run folder (a second ``train`` there is refused; a run is only
continued with ``resume`` or replaced with ``force``), builds the trainer from the cache's clips
with the config file's overrides and fits it. This module imports nothing heavy, so the command
line reads :class:`TrainOptions`' defaults for ``--help``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from facecapges.errors import echo

if TYPE_CHECKING:
    from facecapges.data.cache import Cache

SPLITS = ("train", "val", "test", "all")
RUN_FILES = ("model.safetensors", "log.csv", "summary.json")


@dataclass
class TrainOptions:
    """The options of ``train`` (``facecapges train --help`` says what each does)."""

    cache: Path
    speaker: int
    out: Path
    config: Path | None = None
    epochs: int | None = None
    split: str | None = None
    holdout_from: int | None = None
    init_from: str | None = None
    resume: bool = False
    force: bool = False
    device: str = "auto"
    amp: bool = False


def _run_folder(o: TrainOptions) -> tuple[str, dict | None]:
    """Rank 0: check and lock ``o.out``; (the split to train on, the state to resume or None)."""
    from facecapges.errors import UserError, check_output_dir
    from facecapges.training.resume_file import RunFolderLock
    from facecapges.training.train import load_resume

    if not o.resume and not (o.out / "last.pt").exists():  # a folder without a run keeps its files too
        check_output_dir(o.out, RUN_FILES, o.force)
    check_output_dir(o.out)
    RunFolderLock(o.out).acquire()  # held until the process ends; a second train here is refused
    state = load_resume(o.out) if o.resume else None
    chosen = o.split if o.split is not None else (state["meta"].get("split", "train") if state else "train")
    if chosen not in SPLITS:
        raise UserError(f"--split must be train, val, test or all, got {chosen!r}")
    if (o.out / "last.pt").exists() and not (o.resume or o.force):
        raise UserError(f"{o.out}: holds a training run; pass --resume to continue it or --force to start over")
    return chosen, state


def check_options(o: TrainOptions) -> None:
    """The checks that need no torch, before it loads: the cache and the speaker's clips in the split, the
    config file, the numbers, the run folder (a typo is reported in a second, not after the start-up)."""
    from facecapges.data.cache import Cache
    from facecapges.errors import UserError, check_output_dir, require_file

    if o.split is not None and o.split not in SPLITS:
        raise UserError(f"--split must be train, val, test or all, got {o.split!r}")
    if o.epochs is not None and o.epochs < 1:
        raise UserError("--epochs must be at least 1")
    if o.config is not None:
        from facecapges.network.config import load_config_file

        load_config_file(require_file(o.config, "config file"))
    if o.resume:  # the run's own state (read with torch) says the rest
        return
    has_run = (o.out / "last.pt").exists()
    if not has_run:  # a folder without a run keeps its files too
        check_output_dir(o.out, RUN_FILES, o.force)
    elif not o.force:
        raise UserError(f"{o.out}: holds a training run; pass --resume to continue it or --force to start over")
    Cache(o.cache).select(o.speaker, o.split or "train")


def _data_sources(cache: Cache, speaker: int, names: list[str]) -> dict:
    """The dataset of every trained clip and the speaker's licence, as ``prepare`` recorded them."""
    entries = {e["name"]: e for e in cache.clips(speaker=speaker)}
    info = cache.speaker_info(speaker)
    return {
        "clips": [{"name": n, "dataset": entries[n].get("dataset", info.get("dataset"))} for n in names],
        "licence": info.get("licence"),
        "performer": info.get("performer"),
    }


def train_run(o: TrainOptions, say: Callable[..., None] = echo) -> None:
    """The whole ``train`` command (module docstring); only rank 0 ``say``\\ s anything."""
    check_options(o)  # before torch loads
    from facecapges.errors import UserError
    from facecapges.network.config import load_config_file
    from facecapges.timing import MODEL_FPS
    from facecapges.training.distributed import init_distributed, shutdown
    from facecapges.training.segments import load_clips
    from facecapges.training.train import build_trainer

    ctx = init_distributed(o.device)
    try:
        if not ctx.is_main:
            say = lambda *a, **k: None  # noqa: E731 - the other ranks are silent
        chosen_split, state = ctx.run_on_main(lambda: _run_folder(o))  # rank 0's disk decides
        model_over, train_over = load_config_file(o.config) if o.config else ({}, {})
        if o.epochs is not None:
            if o.epochs < 1:
                raise UserError("--epochs must be at least 1")
            train_over["epochs"] = o.epochs
        if o.holdout_from is not None:  # one frame for every clip replaces the config's fraction
            train_over["holdout_from"] = o.holdout_from
            train_over.pop("holdout_fraction", None)
        if o.init_from is not None:
            train_over["init_from"] = o.init_from
        cache_obj, clips = load_clips(o.cache, o.speaker, chosen_split)
        if abs(cache_obj.fps - model_over.get("fps", MODEL_FPS)) > 1e-6:
            model_over["fps"] = int(round(cache_obj.fps))
        meta = {
            "speaker": o.speaker,
            "clips": [c.name for c in clips],
            "split": chosen_split,
            "skeleton": cache_obj.index["skeleton"],
            "cache": str(o.cache),
            # where the training data came from (prepare's index): a style's card and its licence follow it
            "data": _data_sources(cache_obj, o.speaker, [c.name for c in clips]),
        }
        if o.amp and ctx.device.type != "cuda":
            say("note: --amp is GPU-only; training on CPU in float32", err=True)
        trainer = build_trainer(clips, o.out, model_over, train_over, meta, o.resume, state=state, dist=ctx, amp=o.amp)
        say(
            f"training on {len(clips)} clip(s), {len(trainer.train_set)} segments"
            + (f", {len(trainer.held_set)} held-out" if trainer.held_set else "")
            + f"; epochs {trainer.epoch}/{trainer.tcfg.epochs}"
            + (
                f"; {ctx.world_size} processes, global batch {trainer.global_batch}, lr_g {trainer.lr_g:.3g}"
                if ctx.enabled
                else ""
            )
        )
        trainer.fit()
        ctx.barrier()  # every rank done with its collectives before any tears the group down (a gloo abort else)
        say(f"checkpoint: {o.out / 'model.safetensors'}  log: {o.out / 'log.csv'}")
    finally:
        shutdown(ctx)
