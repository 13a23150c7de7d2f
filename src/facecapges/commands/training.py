"""Commands of the training area: ``train``."""

from __future__ import annotations

from pathlib import Path

import typer

from facecapges.training.launch import TrainOptions


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
        TrainOptions.resume,
        "--resume",
        help="Continue the run in OUT exactly where it stopped (any number of processes).",
    ),
    force: bool = typer.Option(TrainOptions.force, "--force", help="Start over in a run folder that has a run."),
    device: str = typer.Option(
        TrainOptions.device,
        help="auto (a GPU when there is one), cpu or cuda; under torchrun each process takes GPU LOCAL_RANK.",
    ),
    amp: bool = typer.Option(TrainOptions.amp, "--amp", help="float16 mixed precision on GPU (no effect on CPU)."),
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
    options = TrainOptions(**locals())  # before any other name is bound here
    from facecapges.training.launch import train_run

    train_run(options, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command()(train)
