"""The thesis network's style file (format ``facecapges-checkpoint-1``) and the loaded style.

The file (:mod:`facecapges.engine.files`) holds the generator's weights (float32) and, in its
metadata, the :class:`ModelConfig`, the training config and summary, the cold-start neutral pose
window (N, 47, 6) taken from the training data, the speaker, and the skeleton header (the BEAT
hierarchy the poses belong to, so BVH can be written). :func:`from_file` builds a :class:`NetworkStyle`
from a file's tensors and metadata (:func:`facecapges.styles.load_style` reads the file and
chooses the engine); :func:`save_checkpoint` writes one (a network of this package's family, in
another ``fmt`` too: CaMN, the offline decoder).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

from facecapges.engine.contract import GestureEngine
from facecapges.engine.files import check_meta
from facecapges.errors import UserError, file_error

if TYPE_CHECKING:
    from facecapges.network.batched import BatchedNetworkStreams
    from facecapges.network.network import FaceCapGes
    from facecapges.network.streaming import NetworkStream

FORMAT = "facecapges-checkpoint-1"


@dataclass
class NetworkStyle(GestureEngine):
    """A loaded network style (the thesis network): a :class:`~facecapges.engine.contract.GestureEngine`."""

    model: FaceCapGes  # eval mode
    meta: dict
    path: Path
    engine: ClassVar[str] = "network"  # the motion-matching engine's styles: facecapges.matching
    label: ClassVar[str] = "FaceCapGes"

    @property
    def fps(self) -> int:
        return int(self.meta["model_config"]["fps"])

    def streaming(self) -> NetworkStream:
        from facecapges.network.streaming import NetworkStream

        return NetworkStream(self.model, self.neutral_window)

    def batched(self, capacity: int = 8) -> BatchedNetworkStreams:
        """Many streams of this style stepped as one batch (what ``serve`` runs)."""
        from facecapges.network.batched import BatchedNetworkStreams

        return BatchedNetworkStreams(self.model, self.neutral_window, capacity=capacity)


def save_checkpoint(path: str | Path, model, meta: dict, fmt: str = FORMAT) -> Path:
    """Write weights + metadata (format ``fmt``) atomically (temporary file, then rename)."""
    from safetensors.torch import save_file

    from facecapges.network.config import to_dict

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(meta, format=fmt, model_config=to_dict(model.cfg))
    tensors = {k: v.detach().float().contiguous() for k, v in model.state_dict().items()}
    tmp = path.with_name(path.name + ".part")
    save_file(tensors, str(tmp), metadata={"facecapges": json.dumps(meta)})
    tmp.replace(path)
    return path


def from_file(p: Path, tensors: dict, meta: dict) -> NetworkStyle:
    """The network style in file ``p`` (its tensors and metadata, :func:`facecapges.engine.files.read_file`)."""
    import torch

    from facecapges.network.config import model_config_from_dict
    from facecapges.network.network import FaceCapGes, with_default_norms

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
    check_meta(p, meta)
    try:
        model = FaceCapGes(cfg)
    except ValueError as exc:  # sizes that check one by one but not together (a frame shorter than the FFT)
        raise file_error(p, f"checkpoint's model config is invalid ({exc})") from None
    try:
        model.load_state_dict(with_default_norms(model, {k: v.float() for k, v in tensors.items()}), strict=True)
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise file_error(p, f"weights do not match the checkpoint's model config ({first})") from None
    if not all(torch.isfinite(v).all() for v in model.state_dict().values()):
        raise file_error(p, "checkpoint weights contain NaN or infinite values")
    return NetworkStyle(model=model.eval(), meta=meta, path=p)
