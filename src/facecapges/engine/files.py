"""A style's file: float32 tensors in a ``.safetensors`` file and, in its metadata under
``"facecapges"``, one JSON document (its ``format``, the engine's settings, the cold-start window, the
skeleton, the card's facts).

Every engine's style file is read here (:func:`read_file`, with clear errors for a foreign or corrupt
file) and its contract metadata checked (:func:`check_meta`: the neutral window and the skeleton every
:class:`~facecapges.engine.contract.GestureEngine` reads); what the tensors mean is the engine's own
(:mod:`facecapges.network.style`, :mod:`facecapges.matching.style`). :func:`read_weights` reads a weights file of one
format (a baseline's, the offline decoder's; :func:`facecapges.network.style.save_checkpoint` writes them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from facecapges.errors import file_error
from facecapges.skeleton import skeleton_from_dict


def read_file(p: Path, numpy_formats: tuple[str, ...] = ()) -> tuple[dict, dict | None]:
    """A safetensors file's tensors and its ``"facecapges"`` metadata (None when it has none); clear errors.

    The tensors are torch tensors, or NumPy arrays when the metadata's ``format`` is one of ``numpy_formats``
    (an engine that runs without torch: a matching style's ``live`` never imports it)."""
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(p), framework="numpy") as f:
            raw = (f.metadata() or {}).get("facecapges")
            keys = list(f.keys())
    except (SafetensorError, OSError, ValueError) as exc:
        raise file_error(p, f"not a readable checkpoint ({exc})") from None
    meta = None
    if raw is not None:
        try:
            meta = json.loads(raw)
        except (ValueError, RecursionError):
            raise file_error(p, "checkpoint metadata is corrupt") from None
    framework = "numpy" if isinstance(meta, dict) and meta.get("format") in numpy_formats else "pt"
    try:
        with safe_open(str(p), framework=framework) as f:
            tensors = {k: f.get_tensor(k) for k in keys}
    except (SafetensorError, OSError, ValueError) as exc:
        raise file_error(p, f"not a readable checkpoint ({exc})") from None
    except TypeError as exc:  # a dtype NumPy has not (bfloat16)
        raise file_error(p, f"checkpoint has a tensor NumPy cannot read ({exc})") from None
    return tensors, meta


def read_weights(path: str | Path, fmt: str, what: str) -> tuple[dict, dict]:
    """Tensors and metadata of a weights file of format ``fmt`` (e.g. a baseline's); clear errors otherwise."""
    p = Path(path)
    if not p.is_file():
        raise file_error(p, f"{what} not found")
    tensors, meta = read_file(p)
    meta = meta or {}
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        fmt_found = meta.get("format") if isinstance(meta, dict) else None
        raise file_error(p, f"not a {what} (format {fmt_found!r})")
    return tensors, meta


CHANNEL_NAMES = {f"{a}{k}" for a in "XYZ" for k in ("position", "rotation")}


def check_meta(p: Path, meta: dict) -> None:
    """The metadata every style reads later (neutral window, skeleton): types and shapes, or a UserError."""
    try:
        if "neutral_window" not in meta:
            raise KeyError("no neutral_window")
        w = np.asarray(meta["neutral_window"], dtype=np.float64)
        if w.ndim != 3 or w.shape[0] < 1 or w.shape[1:] != (47, 6) or not (np.abs(w) < 1e3).all():
            raise ValueError(f"neutral_window has shape {w.shape}, expected (N, 47, 6) finite numbers")
        if "skeleton" in meta:
            sk = meta["skeleton"]
            names, parents, channels = sk["names"], [int(x) for x in sk["parents"]], sk["channels"]
            J = len(names)
            offsets = np.asarray(sk["offsets"], dtype=np.float64)
            if not J or len(parents) != J or len(channels) != J or offsets.shape != (J, 3):
                raise ValueError("skeleton arrays of different lengths")
            if not all(isinstance(n, str) for n in names) or len(set(names)) != J:
                raise ValueError("skeleton names are not unique strings")
            if any(not -1 <= q < i for i, q in enumerate(parents)) or not np.isfinite(offsets).all():
                raise ValueError("skeleton parents or offsets out of range")
            if not all(isinstance(c, list) and set(c) <= CHANNEL_NAMES for c in channels):
                raise ValueError("skeleton channels are not BVH channel names")
            skeleton_from_dict(sk)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise file_error(p, f"checkpoint metadata is invalid ({exc.__class__.__name__}: {str(exc)[:120]})") from None
