"""Inference checkpoints ("styles"): one ``.safetensors`` file per speaker model.

The file holds the generator's weights (float32) and, in the safetensors metadata
under ``"facecapges"``, a JSON document with everything needed to run and write
results without the training data: the :class:`ModelConfig`, the training config and
summary, the cold-start neutral pose window (N, 47, 6) taken from the training data,
the speaker, and the skeleton header (the BEAT hierarchy the poses belong to, so BVH
can be written).

Installed styles live in ``facecapges/assets/styles/<name>.safetensors`` with a model
card ``<name>.md``; ``DEFAULT_STYLE`` is the one trained on the shared BEAT clip.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from facecapges.skeleton import skeleton_from_dict
from facecapges.errors import UserError, file_error
from facecapges.skeleton import Skeleton

DEFAULT_STYLE = "beat2-scott-demo"
FORMAT = "facecapges-checkpoint-1"


def styles_dir() -> Path:
    return Path(str(resources.files("facecapges") / "assets" / "styles"))


def list_styles() -> dict[str, Path]:
    d = styles_dir()
    return {p.stem: p for p in sorted(d.glob("*.safetensors"))} if d.is_dir() else {}


def resolve(checkpoint: str | Path | None = None, style: str | None = None) -> Path:
    """Path of a checkpoint given a file, a style name, or neither (the default style)."""
    if checkpoint is not None and style is not None:
        raise UserError("give either --checkpoint or --style, not both")
    if checkpoint is not None:
        p = Path(checkpoint)
        if p.is_dir():
            p = p / "model.safetensors"
        if not p.is_file():
            raise file_error(p, "checkpoint not found")
        return p
    name = style or DEFAULT_STYLE
    styles = list_styles()
    if name not in styles:
        known = ", ".join(styles) or "none installed"
        raise UserError(f"unknown style {name!r} (installed: {known})")
    return styles[name]


@dataclass
class Checkpoint:
    """A loaded inference checkpoint."""

    model: "object"  # FaceCapGes (eval mode)
    meta: dict
    path: Path

    @property
    def skeleton(self) -> Skeleton:
        return skeleton_from_dict(self.meta["skeleton"])

    @property
    def neutral_window(self) -> np.ndarray:
        return np.array(self.meta["neutral_window"], dtype=np.float32)

    @property
    def fps(self) -> int:
        return int(self.meta["model_config"]["fps"])

    def streaming(self):
        from facecapges.model.streaming import StreamingGenerator

        return StreamingGenerator(self.model, self.neutral_window)


def save_checkpoint(path: str | Path, model, meta: dict, fmt: str = FORMAT) -> Path:
    """Write weights + metadata (format ``fmt``) atomically (temporary file, then rename)."""
    from safetensors.torch import save_file

    from facecapges.model.config import to_dict

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(meta, format=fmt, model_config=to_dict(model.cfg))
    tensors = {k: v.detach().float().contiguous() for k, v in model.state_dict().items()}
    tmp = path.with_name(path.name + ".part")
    save_file(tensors, str(tmp), metadata={"facecapges": json.dumps(meta)})
    tmp.replace(path)
    return path


def load_checkpoint(path: str | Path | None = None, style: str | None = None) -> Checkpoint:
    """Load a checkpoint file or installed style; clear errors for corrupt/foreign files."""
    import torch
    from safetensors import SafetensorError, safe_open

    from facecapges.model.config import model_config_from_dict
    from facecapges.model.network import FaceCapGes

    p = resolve(path, style)
    try:
        with safe_open(str(p), framework="pt") as f:
            raw_meta = (f.metadata() or {}).get("facecapges")
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError) as exc:
        raise file_error(p, f"not a readable checkpoint ({exc})") from None
    if raw_meta is None:
        raise file_error(p, "not a FaceCapGes checkpoint (no 'facecapges' metadata)")
    try:
        meta = json.loads(raw_meta)
    except (ValueError, RecursionError):
        raise file_error(p, "checkpoint metadata is corrupt") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        fmt = meta.get("format") if isinstance(meta, dict) else None
        raise file_error(p, f"unsupported checkpoint format {fmt!r} (expected {FORMAT})")
    for key in ("model_config",):
        if key not in meta:
            raise file_error(p, f"checkpoint metadata has no {key!r}: not a complete FaceCapGes checkpoint")
    try:
        cfg = model_config_from_dict(meta["model_config"])
    except UserError as exc:
        raise file_error(p, f"checkpoint's model config is invalid ({exc})") from None
    model = FaceCapGes(cfg)
    try:
        model.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=True)
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise file_error(p, f"weights do not match the checkpoint's model config ({first})") from None
    if not all(torch.isfinite(v).all() for v in model.state_dict().values()):
        raise file_error(p, "checkpoint weights contain NaN or infinite values")
    return Checkpoint(model=model.eval(), meta=meta, path=p)


def load_skeleton(checkpoint_path: str | Path | None = None) -> Skeleton:
    """The BEAT skeleton stored with a checkpoint (default: the default style's)."""
    return load_checkpoint(checkpoint_path).skeleton
