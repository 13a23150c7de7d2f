"""Commands of the training area: ``train``."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def train(
        cache: Path = typer.Option(..., help="A cache written by `facecapges prepare`."),
        speaker: int = typer.Option(..., help="BEAT speaker id: one checkpoint per speaker."),
        out: Path = typer.Option(..., help="Run folder: last.pt, model.safetensors, log.csv."),
        config: Path | None = typer.Option(
            None, help="YAML/JSON with 'model:' and 'train:' overrides (small data: configs/demo-beat2-scott.yaml)."
        ),
        epochs: int | None = typer.Option(None, help="Number of epochs (default 375)."),
        split: str | None = typer.Option(
            None, help="Clips to train on: train (default), val, test or all; a resumed run keeps its own."
        ),
        holdout_from: int | None = typer.Option(None, help="Hold out frames >= this of every clip."),
        init_from: str | None = typer.Option(
            None,
            help="Fine-tune: start from a trained style's weights (a style name or checkpoint with the same model "
            "settings as --config), e.g. one trained on more data.",
        ),
        resume: bool = typer.Option(
            False, "--resume", help="Continue the run in OUT exactly where it stopped (any number of processes)."
        ),
        force: bool = typer.Option(False, "--force", help="Start over in a run folder that has a run."),
        device: str = typer.Option(
            "auto",
            help="auto (a GPU when there is one), cpu or cuda; under torchrun each process takes GPU LOCAL_RANK.",
        ),
        amp: bool = typer.Option(False, "--amp", help="float16 mixed precision on GPU (no effect on CPU)."),
    ) -> None:
        """Train a FaceCapGes model with closed-loop sliding-window rollout.

        Without --config this is the published recipe (SGD, batch 256), meant for full
        BEAT (hours of speech per speaker). On small data (minutes of one speaker) use
        the recipe the shipped styles were trained with: --config
        configs/demo-beat2-scott.yaml (Adam, batch 16, a smaller model; its comments
        give the measurements behind each choice). Walk-through from full BEAT to an
        installed style: docs/train-your-own-style.md. Then `facecapges styles install
        OUT` makes it a --style.

        Runs as is under `torchrun --nproc_per_node=K` (and multi-node): the global
        batch is train.batch_size x K and the learning rates scale with it; rank 0
        writes the run folder.
        """
        from facecapges.errors import UserError
        from facecapges.model.config import load_config_file
        from facecapges.training.distributed import init_distributed, shutdown
        from facecapges.training.train import build_trainer, load_clips, load_resume

        ctx = init_distributed(device)
        try:
            say = typer.echo if ctx.is_main else (lambda *a, **k: None)

            def run_folder() -> tuple[str, dict | None]:  # rank 0's disk decides
                from facecapges.errors import check_output_dir
                from facecapges.training.resume_file import RunFolderLock

                if not resume and not (out / "last.pt").exists():  # a folder without a run keeps its files too
                    check_output_dir(out, ("model.safetensors", "log.csv", "summary.json"), force)
                check_output_dir(out)
                RunFolderLock(out).acquire()  # held until the process ends; a second train here is refused
                state = load_resume(out) if resume else None
                chosen = split if split is not None else (state["meta"].get("split", "train") if state else "train")
                if chosen not in ("train", "val", "test", "all"):
                    raise UserError(f"--split must be train, val, test or all, got {chosen!r}")
                if (out / "last.pt").exists() and not (resume or force):
                    raise UserError(
                        f"{out}: holds a training run; pass --resume to continue it or --force to start over"
                    )
                return chosen, state

            chosen_split, state = ctx.run_on_main(run_folder)
            model_over, train_over = load_config_file(config) if config else ({}, {})
            if epochs is not None:
                if epochs < 1:
                    raise UserError("--epochs must be at least 1")
                train_over["epochs"] = epochs
            if holdout_from is not None:
                train_over["holdout_from"] = holdout_from
            if init_from is not None:
                train_over["init_from"] = init_from
            cache_obj, clips = load_clips(cache, speaker, chosen_split)
            if abs(cache_obj.fps - model_over.get("fps", 15)) > 1e-6:
                model_over["fps"] = int(round(cache_obj.fps))
            meta = {
                "speaker": speaker,
                "clips": [c.name for c in clips],
                "split": chosen_split,
                "skeleton": cache_obj.index["skeleton"],
                "cache": str(cache),
            }
            if amp and ctx.device.type != "cuda":
                say("note: --amp is GPU-only; training on CPU in float32", err=True)
            trainer = build_trainer(clips, out, model_over, train_over, meta, resume, state=state, dist=ctx, amp=amp)
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
            say(f"checkpoint: {out / 'model.safetensors'}  log: {out / 'log.csv'}")
        finally:
            shutdown(ctx)
