"""The speech predictor's training and figures (the model and its streaming: :mod:`facecapges.matching.predictor`).

**Training** (:func:`train_predictor`). Only frames before each take's ``train_until`` are read (the
held-out 20 % is never touched: not its motion, audio, face or head); the last 20 % of those
frames is the validation part, and every target is computed from the motion of its own part only
(a training frame's future never reaches into validation motion, a validation frame's never into
the held-out motion). Segments of :attr:`PredictorSettings.segment` frames; the first 16 frames
of a segment that does not start the take only warm the TCNs up (no loss), so every loss frame sees
exactly the causal context it sees when streaming. Face dropout (the whole segment's face zero: the
"no face" input) and head dropout (the whole segment's head held at the camera-frame identity:
the input an audio file gives, and BEAT's head is the Spine→Neck chain, which moves with the arms).
Adam, early stopping on the validation loss **with the head held still**.

The inputs are standardised by the thesis trainer's own rule
(:func:`facecapges.network.network.input_standardisation`) over the training frames.

:func:`evaluate_predictor` gives the figures of a part ("validation" or "heldout") of takes;
docs/matching.md has those of the shipped style.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from facecapges import rotations as rot
from facecapges import timing
from facecapges.matching.predictor import (
    FORMAT,
    OUTPUT_NAMES,
    VERSION,
    K,
    Predictor,
    PredictorSettings,
    camera_head,
    speaking_frames,
)
from facecapges.matching.takes import Take
from facecapges.matching.targets import TARGET_NAMES, arm_positions, future_targets
from facecapges.network.audio_features import FEATURE_DIM, AudioFeatures
from facecapges.network.config import ModelConfig
from facecapges.network.network import (
    AudioEncoder,
    FaceEncoder,
    HeadEncoder,
    MelFrontend,
    input_standardisation,
    mlp,
    set_input_statistics,
)

VALIDATION_FRACTION = 0.2  # the last 20 % of each take's training frames


# --------------------------------------------------------------------------- the network
class SpeechReader(nn.Module):
    """The thesis's causal encoders + an MLP: per frame (audio, face, head) → K + 1 outputs
    (:mod:`facecapges.matching.predictor`'s docs; its NumPy kernel runs the same weights at run time)."""

    def __init__(self, cfg: ModelConfig, hidden: int, dropout: float = 0.0):
        super().__init__()
        self.cfg = cfg.validate()
        self.dropout = float(dropout)
        self.audio_enc = AudioEncoder(cfg)
        self.face_enc = FaceEncoder(cfg)
        self.head_enc = HeadEncoder(cfg)
        self.out = mlp([cfg.audio_dim + cfg.face_dim + cfg.head_dim, hidden, hidden, K + 1])

    def audio_input(self, audio: torch.Tensor) -> torch.Tensor:
        """(B, T, S) samples, or (B, T, 43) precomputed Mel features → (B, T, C) the audio TCN's input."""
        front = self.audio_enc.frontend
        if isinstance(front, MelFrontend) and audio.shape[-1] == FEATURE_DIM:
            return front.out(F.leaky_relu(front.proj(audio), 0.2))  # MelFrontend.forward past its features
        return front(audio)

    def forward(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
        """Whole sequences, causally: audio (B, T, S | 43), face (B, T, 52), head (B, T, 6) → (B, T, K + 1)."""
        z_a = self.audio_enc.from_features(self.audio_input(audio))
        z = torch.cat([z_a, self.face_enc(face, z_a), self.head_enc(head)], -1)
        return self.out(F.dropout(z, self.dropout, self.training))


def audio_frames(audio: np.ndarray, n_frames: int, cfg: ModelConfig) -> np.ndarray:
    """The network's audio input of ``n_frames`` frames: samples (T, 1067), or Mel features (T, 43)."""
    frames = timing.frame_audio(audio, n_frames, cfg.fps, cfg.sr)
    if cfg.audio_repr == "raw":
        return frames
    with torch.no_grad():
        return AudioFeatures(cfg.sr, cfg.samples_per_frame)(torch.from_numpy(frames)).numpy()


# --------------------------------------------------------------------------- data
def network(predictor: Predictor) -> SpeechReader:
    """The torch network with ``predictor``'s weights, in eval mode (the figures run it over whole recordings)."""
    net = SpeechReader(predictor.cfg, predictor.hidden)
    net.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in predictor.weights.items()})
    return net.eval()


def predict(
    predictor: Predictor, audio: np.ndarray, face: np.ndarray, head: np.ndarray, net: SpeechReader | None = None
) -> np.ndarray:
    """A whole recording at once: audio (S,), face (T, 52), camera-frame head (T, 6) → (T, K + 1).

    The torch network over the sequence (causal padding; the training side's figures): the same values as
    stepping a :class:`~facecapges.matching.predictor.PredictorStream`, to float32 rounding. ``net``: a
    :func:`network` of ``predictor`` already built.
    """
    net = network(predictor) if net is None else net
    cfg, T = predictor.cfg, len(face)
    with torch.no_grad():
        a = torch.from_numpy(audio_frames(np.asarray(audio, np.float32), T, cfg))[None]
        f = torch.from_numpy(np.asarray(face, np.float32))[None]
        h = torch.from_numpy(np.array(head, np.float32))[None]
        return predictor.outputs(net(a, f, h)[0].numpy())


def take_targets(take: Take, stop: int) -> np.ndarray:
    """:func:`future_targets` (stop, K) of the take's motion before frame ``stop`` only."""
    pose = take.pose[:stop]
    return future_targets(arm_positions(take.skeleton, pose), timing.MODEL_FPS)


@dataclass
class _Part:
    """One take's training frames as arrays: audio input (T, S | 43), face, camera head, targets, labels."""

    name: str
    audio: np.ndarray
    face: np.ndarray
    head: np.ndarray
    targets: np.ndarray  # (T, K) raw units: frames < v0 from the training motion, ≥ v0 from the validation's
    speaking: np.ndarray  # (T,) float
    v0: int  # first validation frame


def _part(take: Take, cfg: ModelConfig, reference: np.ndarray) -> _Part:
    stop = int(take.train_until)
    v0 = int(math.floor(stop * (1.0 - VALIDATION_FRACTION)))
    samples = int(timing.frame_sample_bounds(stop, cfg.fps, cfg.sr)[0])
    audio = np.asarray(take.audio[:samples], np.float32)
    targets = take_targets(take, stop)
    targets[:v0] = take_targets(take, v0)
    return _Part(
        name=take.name,
        audio=audio_frames(audio, stop, cfg),
        face=np.asarray(take.face[:stop], np.float32),
        head=camera_head(take.head[:stop], reference),
        targets=targets,
        speaking=speaking_frames(audio, stop).astype(np.float32),
        v0=v0,
    )


def _input_statistics(parts: list[_Part], cfg: ModelConfig) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Input standardisation from the training frames: the thesis trainer's rule (one implementation)."""
    head = np.concatenate([p.head for p in parts])
    face = np.concatenate([p.face for p in parts])
    audio = np.concatenate([p.audio for p in parts])
    return input_standardisation(head, face, audio, cfg.audio_repr, cfg.n_face)


# --------------------------------------------------------------------------- training
WARM = 16  # frames a segment's TCNs need before their output equals the streaming one (receptive field − 1)


class _Batches:
    """Random training segments of the parts' frames < v0, with face and head dropout (module docs)."""

    def __init__(self, parts: list[_Part], s: PredictorSettings, mean: np.ndarray, sd: np.ndarray, seed: int):
        self.L = max(2, min([s.segment] + [p.v0 for p in parts]))
        self.s, self.rng = s, np.random.default_rng(seed)
        self.parts = [p for p in parts if p.v0 >= self.L]
        self.tensors = [
            tuple(torch.from_numpy(np.ascontiguousarray(x)) for x in (p.audio, p.face, p.head, (p.targets - mean) / sd))
            + (torch.from_numpy(p.speaking),)
            for p in self.parts
        ]
        n = np.array([p.v0 - self.L + 1 for p in self.parts], np.float64)
        self.weights = n / n.sum()
        self.identity = torch.from_numpy(rot.identity_rot6d().astype(np.float32))

    def sample(self) -> tuple[torch.Tensor, ...]:
        """audio, face, head (B, L, …), normalised targets (B, L, K), speaking (B, L), loss mask (B, L)."""
        B, L = self.s.batch, self.L
        which = self.rng.choice(len(self.parts), size=B, p=self.weights)
        rows = []
        for k in which:
            start = int(self.rng.integers(0, self.parts[k].v0 - L + 1))
            rows.append([x[start : start + L] for x in self.tensors[k]] + [start])
        audio, face, head, tgt, spk = (torch.stack([r[i] for r in rows]) for i in range(5))
        mask = torch.ones(B, L)
        for b, r in enumerate(rows):
            if r[5] > 0:
                mask[b, : min(WARM, L - 1)] = 0.0  # the TCNs' zero padding is not the take's past
        face = face * (torch.from_numpy(self.rng.random(B) >= self.s.face_dropout).float()[:, None, None])
        still = torch.from_numpy(self.rng.random(B) < self.s.head_dropout)
        head = torch.where(still[:, None, None], self.identity.expand_as(head), head)
        return audio, face, head, tgt, spk, mask


def _loss(out: torch.Tensor, tgt: torch.Tensor, spk: torch.Tensor, mask: torch.Tensor, w_spk: float):
    """Masked mean squared error of the normalised targets + w · the speaking logit's cross-entropy."""
    m = mask / mask.sum().clamp(min=1.0)
    mse = (((out[..., :K] - tgt) ** 2).mean(-1) * m).sum()
    bce = (F.binary_cross_entropy_with_logits(out[..., K], spk, reduction="none") * m).sum()
    return mse + w_spk * bce, mse, bce


@torch.no_grad()
def _validation_loss(net: SpeechReader, parts: list[_Part], mean, sd, w_spk: float, still: bool) -> float:
    """The loss over every part's validation frames (the whole training part encoded: causal context)."""
    total, n = 0.0, 0
    ident = torch.from_numpy(rot.identity_rot6d().astype(np.float32))
    for p in parts:
        if p.v0 >= len(p.targets):
            continue
        head = torch.from_numpy(p.head)[None]
        if still:
            head = ident.expand_as(head)
        out = net(torch.from_numpy(p.audio)[None], torch.from_numpy(p.face)[None], head)[0, p.v0 :]
        tgt = torch.from_numpy((p.targets[p.v0 :] - mean) / sd)
        loss, _, _ = _loss(out, tgt, torch.from_numpy(p.speaking[p.v0 :]), torch.ones(len(tgt)), w_spk)
        total, n = total + float(loss) * len(tgt), n + len(tgt)
    return total / max(n, 1)


def train_predictor(
    takes: list[Take], *, seed: int = 0, progress: bool = True, settings: PredictorSettings | None = None
) -> Predictor:
    """Train the speech reader on the takes' frames before ``train_until`` (module docs)."""
    s = settings or PredictorSettings()
    if not takes:
        raise ValueError("train_predictor needs at least one take")
    torch.manual_seed(seed)
    cfg = s.model_config()
    from facecapges.rotations import mean_rotation

    reference = mean_rotation(np.concatenate([t.head[: t.train_until] for t in takes]))
    parts = [_part(t, cfg, reference) for t in takes]
    train_t = np.concatenate([p.targets[: p.v0] for p in parts]).astype(np.float64)
    mean, sd = train_t.mean(0), np.maximum(train_t.std(0), 1e-6)
    net = SpeechReader(cfg, s.hidden, s.dropout)
    set_input_statistics(net, _input_statistics(parts, cfg))
    best, history = _fit(net, parts, s, mean.astype(np.float32), sd.astype(np.float32), seed, progress)
    net.load_state_dict(best)
    config = {
        "format": FORMAT,
        "version": VERSION,
        "outputs": list(OUTPUT_NAMES),
        "settings": asdict(s),
        "model": _json(asdict(cfg)),
        "target_mean": [float(x) for x in mean],
        "target_sd": [float(x) for x in sd],
        "head_reference": [float(x) for x in np.asarray(reference).reshape(6)],
        "takes": [t.name for t in takes],
        "seed": int(seed),
        "training": history,
    }
    pred = Predictor({k: v.detach().numpy() for k, v in net.state_dict().items()}, config)
    own = [t for t in takes if not t.mirrored] or takes  # a mirror has the same audio and targets
    config["validation"] = _finite_json(evaluate_predictor(pred, own, "validation"))
    return pred


def _finite_json(x: Any) -> Any:
    """``x`` with NaN / inf floats as None (strict JSON)."""
    if isinstance(x, dict):
        return {k: _finite_json(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite_json(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _fit(net: SpeechReader, parts: list[_Part], s: PredictorSettings, mean, sd, seed: int, progress: bool):
    """Adam with early stopping on the head-still validation loss → (best weights, a summary of the run)."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    from facecapges.progress import Progress

    batches = _Batches(parts, s, mean, sd, seed)
    opt = torch.optim.AdamW(net.parameters(), lr=s.lr, weight_decay=s.weight_decay)
    best_loss, best, best_step, waited, step = math.inf, copy.deepcopy(net.state_dict()), 0, 0, 0
    columns = (TextColumn("[bold]speech predictor"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, TextColumn("{task.fields[info]}"), disable=not progress, transient=True) as bar:
        task = bar.add_task("speech predictor", total=s.steps, info="")
        for step in range(1, s.steps + 1):
            net.train()
            audio, face, head, tgt, spk, mask = batches.sample()
            loss, _, _ = _loss(net(audio, face, head), tgt, spk, mask, s.speaking_weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            if step % s.eval_every == 0 or step == s.steps:
                net.eval()
                val = _validation_loss(net, parts, mean, sd, s.speaking_weight, still=True)
                if val < best_loss:
                    best_loss, best, best_step, waited = val, copy.deepcopy(net.state_dict()), step, 0
                else:
                    waited += 1
                bar.update(task, info=f"validation {val:.3f} (best {best_loss:.3f} at {best_step})")
                if waited >= s.patience:
                    break
            bar.update(task, advance=1)
    return best, {"steps": step, "best_step": best_step, "validation_loss_head_still": best_loss}


def _json(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


# --------------------------------------------------------------------------- figures
def evaluation_frames(take: Take, part: str) -> tuple[int, int, np.ndarray]:
    """(first, stop, targets (stop − first, K)) of a take's ``part``: "validation" (the last 20 % of
    the training frames, motion before ``train_until`` only) or "heldout" (frames ≥ ``train_until``)."""
    stop = int(take.train_until)
    if part == "validation":
        first = int(math.floor(stop * (1.0 - VALIDATION_FRACTION)))
        return first, stop, take_targets(take, stop)[first:]
    if part == "heldout":
        return stop, take.n_frames, take_targets(take, take.n_frames)[stop:]
    raise ValueError(f"part must be 'validation' or 'heldout', got {part!r}")


def evaluate_predictor(predictor: Predictor, takes: list[Take], part: str = "validation") -> dict[str, Any]:
    """Per target the correlation and R² (against the part's own mean) of predicted vs real, with the
    take's head and with the head held still (identity), also against the training frames' mean
    (the constant a predictor that learnt nothing would give), and the speaking probability's ROC AUC
    against :func:`speaking_frames` of the part's audio. Inputs run causally from the take's start
    to the part's end (never past it)."""
    from sklearn.metrics import roc_auc_score

    rows: dict[str, list[np.ndarray]] = {"real": [], "head": [], "still": [], "speaking": []}
    net = network(predictor)
    for t in takes:
        first, stop, real = evaluation_frames(t, part)
        if stop <= first:
            continue
        samples = int(timing.frame_sample_bounds(stop)[0])
        head = predictor.camera_head(t.head[:stop])
        still = np.broadcast_to(rot.identity_rot6d().astype(np.float32), head.shape)
        rows["real"].append(real)
        rows["head"].append(predict(predictor, t.audio[:samples], t.face[:stop], head, net)[first:])
        rows["still"].append(predict(predictor, t.audio[:samples], t.face[:stop], still, net)[first:])
        rows["speaking"].append(speaking_frames(t.audio[:samples], stop)[first:])  # the VAD from the take's start
    real, spk = np.concatenate(rows["real"]), np.concatenate(rows["speaking"])
    out: dict[str, Any] = {"part": part, "frames": len(real), "takes": [t.name for t in takes]}
    for which in ("head", "still"):
        pred = np.concatenate(rows[which])
        per = {}
        for k, name in enumerate(TARGET_NAMES):
            y, p = real[:, k].astype(np.float64), pred[:, k].astype(np.float64)
            r = float(np.corrcoef(y, p)[0, 1]) if y.std() > 0 and p.std() > 0 else float("nan")
            sse = float(((y - p) ** 2).sum())
            r2 = 1.0 - sse / max(float(((y - y.mean()) ** 2).sum()), 1e-12)
            skill = 1.0 - sse / max(float(((y - predictor.mean[k]) ** 2).sum()), 1e-12)
            per[name] = {"r": r, "r2": r2, "r2_vs_training_mean": skill}
        auc = float(roc_auc_score(spk, pred[:, K])) if 0 < spk.mean() < 1 else float("nan")
        out["real_head" if which == "head" else "head_still"] = {"targets": per, "speaking_auc": auc}
    out["speaking_share"] = float(spk.mean())
    return out
