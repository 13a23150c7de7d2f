"""Matching styles on disk: one ``.safetensors`` of format ``facecapges-matching-1``.

Like the network's styles (:mod:`facecapges.model.checkpoint`), the file holds tensors and, in
the safetensors metadata under ``"facecapges"``, a JSON document:

* tensors ``db.*`` — the :class:`~facecapges.matching.database.Database` arrays (poses, raw
  features, annotations, normalisation); ``predictor.*`` — the speech predictor's weights (absent:
  a style without predictor, which then matches on speech cues alone); ``director.*`` — the weights
  of the style's own thesis network whose wrist direction is a query term
  (:mod:`facecapges.matching.director`; absent in styles without one);
* meta — ``format``, ``engine: "matching"``, ``engine_config`` (:class:`EngineConfig`),
  ``database`` (feature weights, the take segments with their frame ranges), ``predictor`` (its
  JSON config, or null), ``director`` (the network's config and neutral window, or absent), ``skeleton`` (as the network's checkpoints store it), ``neutral_window``
  (idle frames of the style, (N, 47, 6)), ``fps``, ``speaker``, ``takes`` (name, source, frames
  used, held-out range), ``licence`` and ``attribution``.

:func:`facecapges.model.checkpoint.load_checkpoint` reads this format and returns a
:class:`MatchingCheckpoint`: a :class:`~facecapges.model.engine.GestureEngine` like the network's
:class:`~facecapges.model.checkpoint.Checkpoint` (its ``skeleton`` and ``neutral_window`` come from the
metadata the same way), with the engine's ``database_poses()``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from facecapges import timing
from facecapges.errors import UserError, file_error
from facecapges.matching.database import Database
from facecapges.matching.engine import BatchedMatchingGenerator, EngineConfig, MatchingGenerator
from facecapges.model.engine import GestureEngine
from facecapges.skeleton import Skeleton, skeleton_from_dict, skeleton_to_dict

FORMAT = "facecapges-matching-1"
NEUTRAL_FRAMES = 8


@dataclass
class MatchingCheckpoint(GestureEngine):
    """A loaded matching style (module docs): a :class:`~facecapges.model.engine.GestureEngine`."""

    db: Database
    config: EngineConfig
    predictor: object | None
    meta: dict
    path: Path
    director: object | None = None
    engine: ClassVar[str] = "matching"
    label: ClassVar[str] = "motion matching"

    @property
    def fps(self) -> int:
        return int(self.meta["fps"])

    def streaming(self) -> MatchingGenerator:
        return MatchingGenerator(self.db, self.config, self.predictor, self.director)

    def batched(self, capacity: int = 8) -> BatchedMatchingGenerator:
        return BatchedMatchingGenerator(self.db, self.config, self.predictor, capacity=capacity, director=self.director)

    def database_poses(self) -> np.ndarray:
        """Every pose of the database (N, 47, 6) rot6d (the style's real frames and their mirrors)."""
        return self.db.pose


def neutral_window(db: Database, n: int = NEUTRAL_FRAMES) -> np.ndarray:
    """``n`` consecutive idle frames of the database (the cold-start pose of the style)."""
    gen = MatchingGenerator(db)
    start = gen.playing_row
    rows = np.minimum(np.arange(start, start + n), len(db) - 1)
    return db.pose[rows]


def save_matching_style(
    path: str | Path,
    db: Database,
    config: EngineConfig,
    skeleton: Skeleton,
    predictor=None,
    extra: dict | None = None,
    director=None,
) -> Path:
    """Write a matching style atomically (temporary file, then rename); returns its path."""
    import torch
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in db.tensors().items()}
    if predictor is not None:
        tensors.update({f"predictor.{k}": v.detach().float().contiguous() for k, v in predictor.state_dict().items()})
    if director is not None:
        tensors.update({f"director.{k}": v for k, v in director.state_dict().items()})
    meta = dict(extra or {})
    meta.update(
        format=FORMAT,
        engine="matching",
        engine_config=config.as_dict(),
        database=db.meta(),
        predictor=None if predictor is None else predictor.config,
        **({} if director is None else {"director": director.config}),
        skeleton=skeleton_to_dict(skeleton),
        neutral_window=np.round(neutral_window(db).astype(np.float64), 6).tolist(),
        fps=timing.MODEL_FPS,
    )
    tmp = path.with_name(path.name + ".part")
    save_file(tensors, str(tmp), metadata={"facecapges": json.dumps(meta)})
    tmp.chmod(0o644)  # readable like any installed file (the writer creates it private)
    tmp.replace(path)
    return path


def from_file(path: Path, tensors: dict, meta: dict) -> MatchingCheckpoint:
    """A :class:`MatchingCheckpoint` from a file's tensors and meta (clear errors for incomplete files)."""
    for key in ("engine_config", "database", "skeleton", "neutral_window", "fps"):
        if key not in meta:
            raise file_error(path, f"matching style metadata has no {key!r}: not a complete style")
    db_t = {k: v.numpy() for k, v in tensors.items() if k.startswith("db.")}
    try:
        db = Database.from_tensors(db_t, meta["database"])
        config = EngineConfig.from_dict(meta["engine_config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise file_error(path, f"matching style database is incomplete ({exc})") from None
    if not all(np.isfinite(v).all() for v in db_t.values() if v.dtype.kind == "f"):
        raise file_error(path, "matching style database contains NaN or infinite values")
    predictor = None
    if meta.get("predictor"):
        from facecapges.matching.predictor import Predictor

        p_t = {k[len("predictor.") :]: v.float() for k, v in tensors.items() if k.startswith("predictor.")}
        try:
            predictor = Predictor.from_state(meta["predictor"], p_t)
        except (KeyError, RuntimeError, ValueError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise file_error(path, f"matching style predictor does not load ({first})") from None
    director = _director(path, tensors, meta)
    if int(meta["fps"]) != timing.MODEL_FPS:
        raise UserError(f"{path}: matching style at {meta['fps']} fps; this version runs {timing.MODEL_FPS} fps")
    return MatchingCheckpoint(db=db, config=config, predictor=predictor, meta=meta, path=path, director=director)


def _director(path: Path, tensors: dict, meta: dict):
    """The style's network of the wrist-direction term (:mod:`facecapges.matching.director`), or None."""
    if not meta.get("director"):
        return None
    from facecapges.matching.director import Director

    d_t = {k[len("director.") :]: v for k, v in tensors.items() if k.startswith("director.")}
    try:
        return Director.from_state(meta["director"], d_t, skeleton_from_dict(meta["skeleton"]))
    except (KeyError, RuntimeError, TypeError, ValueError, UserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise file_error(path, f"matching style network does not load ({first})") from None
