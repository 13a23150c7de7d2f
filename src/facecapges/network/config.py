"""Every size and setting of the model and its training, in one place.

A :class:`ModelConfig` and a :class:`TrainConfig` are saved inside every checkpoint;
a checkpoint only loads into a model built from the same ``ModelConfig``. Values are
the thesis's where it gives them (ch. 3, 4, 5.1); the rest are our choices, marked
"(ours)" and explained.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from facecapges.arkit import N_BLENDSHAPES
from facecapges.errors import UserError
from facecapges.skeleton import N_JOINTS, N_TORSO
from facecapges.timing import AUDIO_SR, MODEL_FPS, samples_per_frame


@dataclass
class ModelConfig:
    fps: int = MODEL_FPS
    sr: int = AUDIO_SR
    # audio representation (facecapges.network.audio_features): "raw" = each frame's own
    # 16 kHz samples (table 3.1), zero-padded to ceil(sr/fps) = 1067 and reduced by
    # strided convolutions; "mel" = the frame's log-Mel spectrum + energy + F0 (§2.4.1).
    audio_repr: str = "raw"
    n_history: int = 16  # N: history poses in the window; window = N + 1 frames
    n_joints: int = N_JOINTS
    n_torso: int = N_TORSO
    n_face: int = N_BLENDSHAPES
    # audio encoder (12-layer causal TCN with skips + 2-layer MLP -> 128)
    audio_frontend_channels: tuple[int, ...] = (32, 64, 128)  # (ours) strided conv widths
    audio_tcn_channels: int = 64  # (ours)
    # kernel 2 everywhere; dilations sum to N so the receptive field is exactly N+1
    # frames: an embedding depends on its own causal window only (eq. 3.2).
    audio_tcn_dilations: tuple[int, ...] = (1, 1, 1, 1, 2, 2, 2, 2, 1, 1, 1, 1)
    audio_dim: int = 128
    # face encoder (8-layer causal TCN, audio embedding joined at layer 8, MLP -> 32)
    face_tcn_channels: int = 32  # (ours)
    face_tcn_dilations: tuple[int, ...] = (1, 1, 2, 2, 2, 2, 2, 4)
    face_dim: int = 32
    # head encoder MLP 6 -> 36 -> 12 (eq. 3.12-3.13)
    head_hidden: int = 36
    head_dim: int = 12  # 0 = the "without head pose" ablation
    # decoders: torso LSTM, then upper-limb LSTM conditioned on torso outputs
    lstm_hidden: int = 128  # (ours) chosen for the 2 ms/frame CPU budget
    lstm_layers: int = 1  # (ours)
    mlp_hidden: int = 192  # (ours) two-layer output heads
    dropout: float = 0.1  # (ours) on the fused input, training only
    # discriminator (ours: a small temporal conv net over the M generated frames)
    disc_channels: int = 128

    @property
    def window(self) -> int:
        return self.n_history + 1

    @property
    def samples_per_frame(self) -> int:
        return samples_per_frame(self.fps, self.sr)

    @property
    def pose_dim(self) -> int:
        return self.n_joints * 6

    @property
    def fuse_dim(self) -> int:
        return self.audio_dim + self.face_dim + self.head_dim + self.pose_dim

    def validate(self) -> ModelConfig:
        if self.audio_repr not in ("raw", "mel"):
            raise UserError(f"unsupported audio_repr {self.audio_repr!r} (raw or mel)")
        for name, dil in (("audio", self.audio_tcn_dilations), ("face", self.face_tcn_dilations)):
            if sum(dil) > self.n_history:
                raise UserError(f"{name} TCN receptive field {sum(dil) + 1} exceeds the window N+1={self.window}")
        if len(self.audio_tcn_dilations) != 12 or len(self.face_tcn_dilations) != 8:
            raise UserError("the audio TCN has 12 layers and the face TCN 8 (thesis 3.2.3)")
        return self


@dataclass
class TrainConfig:
    clip_len: int = 34  # L = N + M
    stride: int = 10
    batch_size: int = 256
    lr_base: float = 2.5e-4  # lr_g = lr_base * B / 128 (eq. 5.1)
    d_lr_ratio: float = 0.2  # lr_d = 0.2 * lr_g (eq. 5.2)
    optimizer: str = "sgd"  # "sgd" as in the thesis; "adam" (ours) for tiny data sets
    momentum: float = 0.0  # plain SGD as in the thesis
    epochs: int = 375
    adv_start_epoch: int = 11  # discriminator from this (1-based) epoch on
    huber_beta: float = 0.1
    w_rec: float = 500.0
    w_vel: float = 1000.0
    w_acc: float = 1000.0
    w_adv: float = 0.1
    # (ours) motion amplitude: each channel's sd over the generated frames, slow part
    # (< ~2 Hz) and fast rest, against the real segment's (training.masking.amplitude_loss);
    # 0 = off, the thesis recipe
    w_amp: float = 0.0
    # max grad norm (0 = off, as in the thesis). The thesis recipe has no clipping; at
    # 1.0 a start-of-training norm of ~28 makes every plain-SGD step ~28x smaller.
    grad_clip: float = 0.0
    normalize_inputs: bool = True  # (ours) standardise audio/face/head by training-frame statistics
    head_to_camera: bool = True  # map skeleton head rotations into the model's camera frame
    seed: int = 0
    holdout_from: int | None = None  # frames >= this of every clip are held out
    # (or) the last fraction of every clip is held out: frames >= floor(T·(1 − f)) —
    # the cache's rule for takes of other sources (their ``holdout_from``)
    holdout_fraction: float | None = None
    mirror: bool = False  # also train on a left/right mirrored copy of every clip (data/mirror.py)
    # (ours) the chance that a training segment's head input is held still at "facing the
    # camera" (the identity rotation of the model's camera frame) over its whole window:
    # the style then also learns to gesture from the audio alone, the input an audio file
    # without a head track gives it (model.generate: the head at rest). 0 = off.
    head_dropout: float = 0.0
    num_threads: int = 0  # 0 = torch default
    # (ours) fine-tuning: start the generator from a trained style's weights (a checkpoint
    # file or an installed style's name; same model settings) instead of at random. The
    # input statistics and head reference are this run's own speaker's, not the base's.
    init_from: str | None = None

    def learning_rates(self, world_size: int = 1) -> tuple[float, float]:
        """(lr_g, lr_d) by the linear rule on the global batch ``batch_size × world_size`` (eq. 5.1–5.2)."""
        lr_g = self.lr_base * (self.batch_size * world_size) / 128.0
        return lr_g, self.d_lr_ratio * lr_g


# The allowed range of every setting: (least, greatest) — None is open — or the allowed
# values; checked with the type of the field by :func:`check_fields` so a bad value is one
# message naming the setting, never a traceback deep in training.
LIMITS: dict[str, dict[str, tuple | set]] = {
    "ModelConfig": {
        "fps": (1, 240),
        "sr": (8000, 192000),
        "audio_repr": {"raw", "mel"},
        "n_history": (1, 256),
        "n_joints": {47},
        "n_torso": (1, 46),
        "n_face": {52},
        "audio_frontend_channels": (1, 4096),
        "audio_tcn_channels": (1, 4096),
        "audio_tcn_dilations": (1, 256),
        "audio_dim": (1, 4096),
        "face_tcn_channels": (1, 4096),
        "face_tcn_dilations": (1, 256),
        "face_dim": (1, 4096),
        "head_hidden": (1, 4096),
        "head_dim": (0, 4096),
        "lstm_hidden": (1, 4096),
        "lstm_layers": (1, 16),
        "mlp_hidden": (1, 8192),
        "dropout": (0.0, 0.99),
        "disc_channels": (1, 4096),
    },
    "TrainConfig": {
        "clip_len": (2, 100_000),
        "stride": (1, 100_000),
        "batch_size": (1, 1 << 20),
        "lr_base": (1e-12, 100.0),
        "d_lr_ratio": (0.0, 1000.0),
        "optimizer": {"sgd", "adam"},
        "momentum": (0.0, 0.999),
        "epochs": (1, 1_000_000),
        "adv_start_epoch": (1, 1_000_000),
        "huber_beta": (1e-9, 1000.0),
        "w_rec": (0.0, 1e9),
        "w_vel": (0.0, 1e9),
        "w_acc": (0.0, 1e9),
        "w_adv": (0.0, 1e9),
        "w_amp": (0.0, 1e9),
        "grad_clip": (0.0, 1e9),
        "seed": (0, 2**32 - 1),
        "holdout_from": (1, None),
        "num_threads": (0, 1024),
        "holdout_fraction": (0.0, 0.9),
        "head_dropout": (0.0, 1.0),
    },
}


def _check_value(where: str, kind: str, v, limits):
    """One setting against its type (the field's annotation) and its limits; returns the clean value."""

    def bad(expected: str):
        return UserError(f"{where} must be {expected}, got {v!r}")

    if kind.endswith("| None"):
        if v is None:
            return None
        kind = kind[: -len("| None")].strip()
    if kind.startswith("tuple["):
        if not isinstance(v, (list, tuple)) or not v:
            raise bad("a non-empty list of whole numbers")
        return tuple(_check_value(f"{where}[{i}]", "int", x, limits) for i, x in enumerate(v))
    if kind == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            raise bad("a whole number")
    elif kind == "float":
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or v in (float("inf"), float("-inf")):
            raise bad("a number")
        v = float(v)
    elif kind == "str" and not isinstance(v, str):
        raise bad("a text value")
    if isinstance(limits, set):
        if v not in limits:
            raise bad("one of " + ", ".join(repr(x) for x in sorted(limits)))
    elif limits is not None:
        lo, hi = limits
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise bad(f"at least {lo}" if hi is None else f"between {lo} and {hi}")
    return v


def check_fields(cls, data) -> dict:
    """``data`` checked against the settings of ``cls`` (names, types, ranges); the clean keyword arguments."""
    section = {"ModelConfig": "model", "TrainConfig": "train"}.get(cls.__name__, cls.__name__)
    if not isinstance(data, dict):
        raise UserError(f"the '{section}' settings must be a mapping of name: value, got {data!r}")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(map(str, data)) - names)
    if unknown:
        raise UserError(f"unknown {cls.__name__} setting(s): {', '.join(unknown)}")
    limits = LIMITS.get(cls.__name__, {})
    return {
        f.name: _check_value(f"{section}.{f.name}", str(f.type), data[f.name], limits.get(f.name))
        for f in fields(cls)
        if f.name in data
    }


def _from_dict(cls, data: dict):
    return cls(**check_fields(cls, data))


def model_config_from_dict(data: dict) -> ModelConfig:
    return _from_dict(ModelConfig, data).validate()


def train_config_from_dict(data: dict, model: ModelConfig | None = None) -> TrainConfig:
    cfg = _from_dict(TrainConfig, data)
    if model is not None and cfg.clip_len <= model.n_history:
        raise UserError(
            f"train.clip_len must be more than model.n_history = {model.n_history} (the warm-up "
            f"frames; the rest are generated), got {cfg.clip_len}"
        )
    return cfg


def to_dict(cfg) -> dict:
    return json.loads(json.dumps(asdict(cfg)))


def load_config_file(path: str | Path) -> tuple[dict, dict]:
    """Read a YAML/JSON file with optional ``model:`` and ``train:`` sections."""
    import yaml

    from facecapges.io.yaml_text import safe_load

    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: config file not found")
    try:
        data = safe_load(p.read_text(encoding="utf-8")) or {}
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not valid YAML/JSON ({exc.__class__.__name__})") from None
    if not isinstance(data, dict) or set(data) - {"model", "train"}:
        raise UserError(f"{p}: expected a mapping with 'model' and/or 'train' sections")
    model, train = data.get("model") or {}, data.get("train") or {}
    for name, section in (("model", model), ("train", train)):
        if not isinstance(section, dict):
            raise UserError(f"{p}: '{name}:' must be a mapping of settings, got {section!r}")
    try:  # every value now, before any data is read
        train_config_from_dict(dict(train), model_config_from_dict(dict(model)))
    except UserError as exc:
        raise UserError(f"{p}: {exc}") from None
    return dict(model), dict(train)
