"""A thesis network trained on a matching style's own training frames, for its wrist-direction query term.

Issue #25: the thesis network's generated wrist direction (its timing follows the speech even where its
amplitude is small) as a further term of the matching engine's query
(:mod:`facecapges.matching.director`). A shipped style must not depend on a network derived from ZEGGS
(CC BY-NC-ND), so the network is trained here from scratch on the style's takes, frames
``[0, stop)`` of each (default: ``train_until``, the first 80 %) and nothing else — the repo's own trainer
(:mod:`facecapges.training.train`) with a small budget (:data:`DIRECTOR_MODEL`, :data:`DIRECTOR_TRAIN`:
the small model and recipe of ``configs/demo-beat2-scott.yaml`` without its ZEGGS initialisation).
"""

from __future__ import annotations

import copy
import tempfile
from collections.abc import Sequence
from pathlib import Path

from facecapges import timing
from facecapges.matching.director import Director
from facecapges.matching.takes import Take
from facecapges.training.segments import ClipArrays, clip_head
from facecapges.training.train import build_trainer

DIRECTOR_MODEL: dict = {
    "audio_repr": "mel",
    "audio_frontend_channels": [16, 32, 64],
    "audio_tcn_channels": 32,
    "audio_dim": 64,
    "face_tcn_channels": 16,
    "face_dim": 16,
    "lstm_hidden": 64,
    "mlp_hidden": 96,
    "disc_channels": 64,
}
DIRECTOR_TRAIN: dict = {
    "batch_size": 16,
    "optimizer": "adam",
    "lr_base": 0.008,
    "epochs": 60,
    "head_dropout": 0.5,
    "w_amp": 1000,
    "w_acc": 5000,
    "mirror": True,
    "num_threads": 1,
}


def train_director(
    takes: Sequence[Take],
    stop: Sequence[int] | None = None,
    epochs: int | None = None,
    seed: int = 0,
    progress: bool = True,
) -> Director:
    """The network trained on frames ``[0, stop[k])`` of each take (default: its ``train_until``)."""
    stops = [t.train_until for t in takes] if stop is None else list(stop)
    clips = []
    for t, b in zip(takes, stops, strict=True):
        if b > t.train_until:
            raise ValueError(f"{t.name}: frames from {t.train_until} on are held out")
        c = ClipArrays(t.name, t.pose, t.head, t.face, t.audio)
        clips.append(clip_head(c, b, timing.MODEL_FPS, timing.AUDIO_SR))
    train = dict(DIRECTOR_TRAIN, seed=seed, **({} if epochs is None else {"epochs": int(epochs)}))
    with tempfile.TemporaryDirectory(prefix="facecapges-director-") as tmp:
        tr = build_trainer(clips, Path(tmp), dict(DIRECTOR_MODEL), train, {}, resume=False)
        tr.fit(progress=progress)
        meta = {
            "neutral_window": tr.neutral.tolist(),
            "head_reference_rot6d": None if tr.head_reference is None else tr.head_reference.tolist(),
            "epochs_trained": tr.epoch,
            "frames_used": [[0, int(b)] for b in stops],
        }
        return Director(copy.deepcopy(tr.G).cpu().eval(), meta, takes[0].skeleton)
