"""Matching styles on disk: one ``.safetensors`` of format ``facecapges-matching-1``.

Like the network's styles (:mod:`facecapges.styles`), the file holds tensors and, in
the safetensors metadata under ``"facecapges"``, a JSON document:

* tensors ``db.*`` — the :class:`~facecapges.matching.database.Database` arrays (poses, raw
  features, annotations, normalisation; a ``db.energy_class`` of files written before issue #35 is
  ignored); ``predictor.*`` — the speech predictor's weights (absent:
  a style without predictor, which then matches on speech cues alone). Files written before the
  "director" experiment was removed (docs/matching.md) may carry ``director.*`` tensors and a
  ``director`` meta entry: they are ignored;
* meta — ``format``, ``engine: "matching"``, ``engine_config`` (:class:`MatchingConfig`),
  ``database`` (feature weights, the take segments with their frame ranges), ``predictor`` (its
  JSON config, or null), ``skeleton`` (as the network's checkpoints store it), ``neutral_window``
  (idle frames of the style, (N, 47, 6)), ``fps``, ``speaker``, ``takes`` (name, source, frames
  used, held-out range), ``licence`` and ``attribution``.

:func:`facecapges.styles.load_style` reads this format and returns a
:class:`MatchingStyle`: a :class:`~facecapges.engine.contract.GestureEngine` like the network's
:class:`~facecapges.network.style.NetworkStyle` (its ``skeleton`` and ``neutral_window`` come from the
metadata the same way), with the engine's ``database_poses()``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from facecapges import timing
from facecapges.engine.contract import GestureEngine
from facecapges.errors import UserError, file_error
from facecapges.matching.database import Database
from facecapges.matching.matcher import BatchedMatchingStreams, MatchingConfig, MatchingStream
from facecapges.skeleton import Skeleton, skeleton_to_dict

FORMAT = "facecapges-matching-1"
NEUTRAL_FRAMES = 8


@dataclass
class MatchingStyle(GestureEngine):
    """A loaded matching style (module docs): a :class:`~facecapges.engine.contract.GestureEngine`."""

    db: Database
    config: MatchingConfig
    predictor: object | None
    meta: dict
    path: Path
    engine: ClassVar[str] = "matching"
    label: ClassVar[str] = "motion matching"

    @property
    def fps(self) -> int:
        return int(self.meta["fps"])

    def streaming(self) -> MatchingStream:
        return MatchingStream(self.db, self.config, self.predictor, skeleton=self.skeleton)

    def batched(self, capacity: int = 8) -> BatchedMatchingStreams:
        return BatchedMatchingStreams(self.db, self.config, self.predictor, capacity=capacity, skeleton=self.skeleton)

    def database_poses(self) -> np.ndarray:
        """Every pose of the database (N, 47, 6) rot6d (the style's real frames and their mirrors)."""
        return self.db.pose


def neutral_window(db: Database, n: int = NEUTRAL_FRAMES) -> np.ndarray:
    """``n`` consecutive idle frames of the database (the cold-start pose of the style)."""
    gen = MatchingStream(db)
    start = gen.playing_row
    rows = np.minimum(np.arange(start, start + n), len(db) - 1)
    return db.pose[rows]


def save_matching_style(
    path: str | Path,
    db: Database,
    config: MatchingConfig,
    skeleton: Skeleton,
    predictor=None,
    extra: dict | None = None,
) -> Path:
    """Write a matching style atomically (temporary file, then rename); returns its path."""
    import torch
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in db.tensors().items()}
    if predictor is not None:
        tensors.update(
            {
                f"predictor.{k}": torch.from_numpy(np.ascontiguousarray(v, np.float32))
                for k, v in predictor.state_dict().items()
            }
        )
    meta = dict(extra or {})
    meta.update(
        format=FORMAT,
        engine="matching",
        engine_config=config.as_dict(),
        database=db.meta(),
        predictor=None if predictor is None else predictor.config,
        skeleton=skeleton_to_dict(skeleton),
        neutral_window=np.round(neutral_window(db).astype(np.float64), 6).tolist(),
        fps=timing.MODEL_FPS,
    )
    tmp = path.with_name(path.name + ".part")
    save_file(tensors, str(tmp), metadata={"facecapges": json.dumps(meta)})
    tmp.chmod(0o644)  # readable like any installed file (the writer creates it private)
    tmp.replace(path)
    return path


#: The range of each :class:`MatchingConfig` setting a style file may hold, (lowest, highest), both allowed. A
#: setting's type is its default's (bool, int or float: finite); a setting not listed here is checked for its
#: type only. Add a row with each new setting.
CONFIG_RANGES: dict[str, tuple[float, float]] = {
    "search_interval": (1, 150),  # frames: at most 10 s between searches
    "margin": (0.0, 1e6),
    "halflife_s": (0.01, 10.0),
    "memory_s": (0.0, 3600.0),
    "memory_penalty": (0.0, 1e6),
    "near_frames": (0, 1000),
    "min_play_frames": (0, 150),  # frames: at most 10 s before a search may leave a clip
    "pause_halflife_s": (0.01, 10.0),
    "accel_cap_percentile": (0.0, 100.0),  # 0: off
    "settle_s": (0.0, 60.0),
    "pause_gain": (0.0, 2.0),
    "intensity_smooth_s": (0.0, 60.0),
    "onset_bonus": (0.0, 1e3),
    "onset_frames": (0, 150),
    "intensity_tau_s": (0.0, 60.0),
    "idle_after_s": (0.0, 60.0),
    "idle_enter_halflife_s": (0.01, 10.0),
    "idle_release_halflife_s": (0.01, 10.0),
    "idle_amplitude": (0.0, 10.0),
    "idle_enter_velocity": (0.0, 1.0),
}
#: The values a text setting may take.
CONFIG_CHOICES: dict[str, tuple[str, ...]] = {
    "idle_rest": ("low", "nearest", "mean"),
    "idle_torso": ("matched", "neck", "procedural"),
}


def check_engine_config(d: object) -> MatchingConfig:
    """An :class:`MatchingConfig` from a style's ``engine_config``, every setting's type and range checked
    (:data:`CONFIG_RANGES`); a ValueError names the first wrong one."""
    import math
    from dataclasses import fields

    if not isinstance(d, dict):
        raise ValueError(f"engine_config is {type(d).__name__}, not an object")
    defaults = MatchingConfig()
    for f in fields(MatchingConfig):
        if f.name not in d:
            continue
        v, default = d[f.name], getattr(defaults, f.name)
        if isinstance(default, bool):
            ok = isinstance(v, bool)
        elif isinstance(default, int):
            ok = isinstance(v, int) and not isinstance(v, bool)
        elif isinstance(default, float):
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        else:
            ok = default is None or isinstance(v, type(default))
        if not ok:
            raise ValueError(f"engine_config {f.name} = {v!r} is not a {type(default).__name__}")
        if f.name in CONFIG_CHOICES and v not in CONFIG_CHOICES[f.name]:
            raise ValueError(f"engine_config {f.name} = {v!r} is not one of {', '.join(CONFIG_CHOICES[f.name])}")
        lo, hi = CONFIG_RANGES.get(f.name, (-math.inf, math.inf))
        if not isinstance(default, bool) and isinstance(v, int | float) and not lo <= v <= hi:
            raise ValueError(f"engine_config {f.name} = {v!r} is outside [{lo:g}, {hi:g}]")
    return MatchingConfig.from_dict(d)


def _check_database(t: dict[str, np.ndarray], meta: object) -> None:
    """Every database array's length and width against ``db.pose``, its kind and values, and the database
    metadata (weights, segments) they index: a ValueError names the first wrong one."""
    from facecapges.matching.database import PHASES
    from facecapges.matching.features import GROUP_NAMES, N_FEATURES
    from facecapges.skeleton import N_JOINTS

    if not isinstance(meta, dict) or not isinstance(meta.get("segments"), list):
        raise ValueError("database metadata is not an object with a 'segments' list")
    w = meta.get("weights")
    if not isinstance(w, dict) or not all(
        k in GROUP_NAMES and isinstance(v, int | float) and not isinstance(v, bool) and 0 <= v < 1e6
        for k, v in w.items()
    ):
        raise ValueError(f"database weights must map {', '.join(GROUP_NAMES)} to numbers ≥ 0")
    seg_fields = {"name": str, "source": str, "start": int, "stop": int, "mirrored": bool, "row": int}
    for seg in meta["segments"]:
        if not isinstance(seg, dict) or set(seg) != set(seg_fields):
            raise ValueError(f"a database segment is not an object of {', '.join(seg_fields)}")
        if not all(
            isinstance(seg[k], typ) and (typ is bool or not isinstance(seg[k], bool)) for k, typ in seg_fields.items()
        ):
            raise ValueError(f"database segment {seg.get('name')!r} has a field of the wrong type")
    if "db.pose" not in t:
        raise ValueError("no db.pose")
    n = len(t["db.pose"]) if t["db.pose"].ndim else 0
    shapes: dict[str, tuple[tuple[int, ...], str]] = {  # key → (shape, kinds of dtype)
        "db.pose": ((n, N_JOINTS, 6), "f"),
        "db.features": ((n, N_FEATURES), "f"),
        "db.pause": ((n,), "biu"),
        "db.phase": ((n,), "iu"),
        "db.lead": ((n,), "f"),
        "db.searchable": ((n,), "biu"),
        "db.segment": ((n,), "iu"),
        "db.mean": ((N_FEATURES,), "f"),
        "db.scale": ((N_FEATURES,), "f"),
    }
    for key, (shape, kinds) in shapes.items():
        if key not in t:
            raise ValueError(f"no {key}")
        a = t[key]
        if a.shape != shape or a.dtype.kind not in kinds:
            raise ValueError(f"{key} is {a.dtype} {a.shape}, expected {shape} of {_kinds(kinds)} (db.pose: {n} frames)")
    ranges = {
        "db.pause": (0, 1),
        "db.searchable": (0, 1),
        "db.phase": (0, len(PHASES) - 1),
        "db.segment": (0, len(meta["segments"]) - 1),
    }
    for key, (lo, hi) in ranges.items():
        a = t[key]
        if n and (a.min() < lo or a.max() > hi):
            raise ValueError(f"{key} holds values outside {lo}…{hi}")
    if n <= 10 or not t["db.searchable"].any():
        raise ValueError(f"the database of {n} frames has no searchable frame")
    if not (t["db.scale"] > 0).all():
        raise ValueError("db.scale holds values ≤ 0")


def _kinds(kinds: str) -> str:
    return " or ".join({"f": "floats", "i": "integers", "u": "integers", "b": "booleans"}[k] for k in kinds[:2])


def from_file(path: Path, tensors: dict, meta: dict) -> MatchingStyle:
    """A :class:`MatchingStyle` from a file's tensors and meta (clear errors for incomplete files)."""
    for key in ("engine_config", "database", "skeleton", "neutral_window", "fps"):
        if key not in meta:
            raise file_error(path, f"matching style metadata has no {key!r}: not a complete style")
    fps = meta["fps"]
    if not isinstance(fps, int) or isinstance(fps, bool) or fps != timing.MODEL_FPS:
        raise file_error(path, f"matching style at fps {fps!r}; this version runs {timing.MODEL_FPS} (a number)")
    db_t = {k: np.asarray(v) for k, v in tensors.items() if k.startswith("db.")}
    try:
        _check_database(db_t, meta["database"])
        config = check_engine_config(meta["engine_config"])
        db = Database.from_tensors(db_t, meta["database"])
    except (KeyError, TypeError, ValueError) as exc:
        raise file_error(path, f"matching style is invalid ({exc})") from None
    if not all(np.isfinite(v).all() for v in db_t.values() if v.dtype.kind == "f"):
        raise file_error(path, "matching style database contains NaN or infinite values")
    predictor = None
    if meta.get("predictor") is not None:
        predictor = _predictor(path, tensors, meta["predictor"])
    return MatchingStyle(db=db, config=config, predictor=predictor, meta=meta, path=path)


def _predictor(path: Path, tensors: dict, config: object):
    """The style's speech predictor; its JSON config checked (sizes through the network's own ranges)."""
    from facecapges.matching.predictor import OUTPUT_NAMES, Predictor
    from facecapges.network.config import model_config_from_dict

    p_t = {k[len("predictor.") :]: v for k, v in tensors.items() if k.startswith("predictor.")}
    try:
        if not isinstance(config, dict):
            raise ValueError(f"predictor is {type(config).__name__}, not an object")
        model_config_from_dict(config["model"])  # every size in its range before anything is allocated
        hidden = config["settings"]["hidden"]
        if not isinstance(hidden, int) or isinstance(hidden, bool) or not 1 <= hidden <= 4096:
            raise ValueError(f"predictor hidden size {hidden!r} is not 1…4096")
        k = len(OUTPUT_NAMES) - 1
        for key, n in (("target_mean", k), ("target_sd", k), ("head_reference", 6)):
            a = np.asarray(config[key], np.float64)
            if a.shape != (n,) or not np.isfinite(a).all():
                raise ValueError(f"predictor {key} is not {n} finite numbers")
        return Predictor.from_state(config, p_t)
    except (KeyError, RuntimeError, ValueError, TypeError, AttributeError, UserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise file_error(path, f"matching style predictor does not load ({first})") from None
