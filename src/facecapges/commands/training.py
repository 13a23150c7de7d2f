"""Commands of the training area: ``train``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import CACHE
from facecapges.training.launch import TrainOptions

SPEAKER = typer.Option("--speaker", help="BEAT speaker id: one checkpoint per speaker.")
OUT = typer.Option("--out", help="Run folder: last.pt, model.safetensors, log.csv.")
CONFIG = typer.Option(
    "--config",
    help="YAML/JSON with 'model:' and 'train:' overrides (small data: configs/demo-beat2-scott.yaml).",
)
EPOCHS = typer.Option("--epochs", help="Number of epochs (default 375).")
SPLIT = typer.Option(
    "--split", help="Clips to train on: train (default), val, test or all; a resumed run keeps its own."
)
HOLDOUT_FROM = typer.Option("--holdout-from", help="Hold out frames >= this of every clip.")
INIT_FROM = typer.Option(
    "--init-from",
    help="Fine-tune: start from a trained style's weights (a style name or checkpoint with the same model "
    "settings as --config), e.g. one trained on more data.",
)
RESUME = typer.Option("--resume", help="Continue the run in OUT exactly where it stopped (any number of processes).")
FORCE = typer.Option("--force", help="Start over in a run folder that has a run.")
DEVICE = typer.Option(
    "--device",
    help="auto (a GPU when there is one), cpu or cuda; under torchrun each process takes GPU LOCAL_RANK.",
)
AMP = typer.Option("--amp", help="float16 mixed precision on GPU (no effect on CPU).")


def train(
    cache: Annotated[Path, CACHE],
    speaker: Annotated[int, SPEAKER],
    out: Annotated[Path, OUT],
    config: Annotated[Path | None, CONFIG] = None,
    epochs: Annotated[int | None, EPOCHS] = None,
    split: Annotated[str | None, SPLIT] = None,
    holdout_from: Annotated[int | None, HOLDOUT_FROM] = None,
    init_from: Annotated[str | None, INIT_FROM] = None,
    resume: Annotated[bool, RESUME] = TrainOptions.resume,
    force: Annotated[bool, FORCE] = TrainOptions.force,
    device: Annotated[str, DEVICE] = TrainOptions.device,
    amp: Annotated[bool, AMP] = TrainOptions.amp,
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
