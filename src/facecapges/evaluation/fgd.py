"""Fréchet Gesture Distance: skeleton-aware motion autoencoder + Fréchet distance.

Thesis 5.5.1. FGD compares the Gaussian statistics of real and generated motion in
the latent space of a motion autoencoder trained per speaker on the train split:

    FGD = ‖μ_r − μ_g‖² + Tr(Σ_r + Σ_g − 2 (Σ_r Σ_g)^{1/2})                  (5.3)

**Input.** Windows of ``window`` = 32 frames of upper-body poses, rot6d (32, J, 6),
cut with ``stride`` = 10 frames (training and, by default, evaluation). Clips shorter
than one window give no window.

**Graph.** The joints are nodes; ``A_ij = 1`` when joint ``i`` is the parent or a
child of ``j`` inside the evaluated joint set, or ``i = j`` (eq. 5.6). A joint's
parent *inside the set* is its nearest ancestor in the BEAT hierarchy that belongs
to the set: Spine is the root, Neck → Spine (over Spine1–3), Neck1 → Neck, each
Shoulder → Spine, Arm → Shoulder, ForeArm → Arm, Hand → ForeArm, the finger chains
as BEAT nests them (Middle1/Ring/Index → Hand, Pinky → Ring, Thumb1 → Index, then
each finger's 1 → 2 → 3). :data:`UPPER_BODY_PARENT` is that table;
:func:`parents_within` derives the same from any :class:`~facecapges.skeleton.Skeleton`.

**Layer (eq. 5.7).** ``h_i' = tanh(Σ_j A_ij W h_j + b)`` with one weight shared by all
joints. Here ``W`` also spans a few frames (a temporal convolution of kernel ``k``,
optionally strided), because the autoencoder must compress time as well as joints;
with ``k = 1`` the layer is exactly eq. 5.7.

**Architecture** (:class:`FGDConfig` holds every size):

* encoder: graph layers 6→c1 (k3), c1→c2 (k4, stride 2), c2→c2 (k4, stride 2), all
  tanh; then per latent time step a linear map of the J·c2 joint features to
  ``hidden`` = 128 — the latent is a sequence (B, window/4, 128);
* decoder: linear 128 → J·c2 + tanh, then twice [nearest ×2 upsampling in time,
  graph layer + tanh], then a graph layer to 6 channels without activation.

``hidden`` = 128 is the thesis's; the per-joint widths c1 = 16, c2 = 32 are ours,
chosen so training fits a CPU (≈ 5–10 s per epoch per 1000 windows on 2 shared cores; see
``facecapges bench --only evaluation``).

**Features for FGD.** Like BEAT/EMAGE's evaluators, every latent time step of every
window is one 128-d sample (``(N·window/4, 128)``).

**Training** (eq. 5.4–5.5): loss ``λ_r‖ĝ−g‖² + λ_v‖ĝ′−g′‖²`` with mean squared
errors over all elements, ``g′`` the frame-to-frame difference, λ_r = 1, λ_v = 0.1;
SGD with ``lr = 1.2e-4 · B/128``, B = 256, 400 epochs. The thesis does not state a
momentum; we use 0.9 (``FGDConfig.momentum``; 0 gives plain SGD).

**Regions.** One autoencoder per evaluation region (thesis 5.5.5,
:mod:`facecapges.evaluation.regions`): the "without head" one is trained on the
45-joint graph without Neck/Neck1, so head rotations never enter its features.

**Numerics of eq. 5.3.** :func:`frechet_distance` uses the symmetric form
``Tr((Σ_r Σ_g)^{1/2}) = Tr((Σ_r^{1/2} Σ_g Σ_r^{1/2})^{1/2})`` (valid for positive
semi-definite Σ) computed with symmetric eigendecompositions and negative
round-off eigenvalues clipped to 0. It is real and finite for rank-deficient
covariances (fewer samples than dimensions, constant features), and gives
≈ 0 for identical statistics. ``method="sqrtm"`` uses ``scipy.linalg.sqrtm`` on the
product instead (with an ε·I offset retry and the tiny imaginary part dropped), and
falls back to the symmetric form when that fails.

**Files** (:func:`fgd_paths`): weights as safetensors (keys prefixed with the region)
plus a JSON document (config, joints per region, training history). Given a
*directory* they are ``DIR/fgd_autoencoder.safetensors`` and ``DIR/fgd_autoencoder.json``;
given a gesture *checkpoint file* ``X/NAME.safetensors`` they go into the folder
``X/NAME.fgd/`` next to it, so every checkpoint (and every installed style) carries
its own FGD autoencoder — and a folder of checkpoints (e.g. the installed styles,
listed by ``*.safetensors``) gains no file that looks like another checkpoint.

**The packaged autoencoder** (:func:`packaged_fgd_dir`, ``facecapges/assets/fgd/beat-upper-body/``, its
card ``README.md`` beside the weights): trained by ``fgd-train`` on BEAT speaker 2's two paired takes
(BEAT 2_scott_0_1_1, BEAT2 2_scott_0_2_2 converted; CC BY-NC 4.0), the first 80 % of each only
(``scripts/train-fgd-autoencoder.sh``). :func:`find_fgd` picks the autoencoder ``facecapges eval``
uses: the one given (``--fgd``), else the checkpoint's own (``NAME.fgd/``), else the packaged one —
so every engine, motion matching included, gets an FGD; the report says which was used.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from facecapges.evaluation.regions import REGIONS, region_indices, region_joints
from facecapges.skeleton import N_JOINTS, UPPER_BODY, Skeleton
from facecapges.timing import MODEL_FPS

FGD_WEIGHTS = "fgd_autoencoder.safetensors"
FGD_CONFIG = "fgd_autoencoder.json"


# ------------------------------------------------------------------------- graph
def _finger_parents(side: str) -> dict[str, str]:
    h = f"{side}Hand"
    p = {
        f"{side}Shoulder": "Spine",
        f"{side}Arm": f"{side}Shoulder",
        f"{side}ForeArm": f"{side}Arm",
        f"{side}Hand": f"{side}ForeArm",
        f"{h}Middle1": h,
        f"{h}Ring": h,
        f"{h}Pinky": f"{h}Ring",
        f"{h}Index": h,
        f"{h}Thumb1": f"{h}Index",
    }
    for finger, first in (("Middle", "Middle1"), ("Ring", "Ring"), ("Pinky", "Pinky"), ("Index", "Index")):
        chain = [first] + [f"{finger}{k}" for k in (1, 2, 3) if f"{finger}{k}" != first]
        for a, b in itertools.pairwise(chain):
            p[f"{h}{b}"] = f"{h}{a}"
    p[f"{h}Thumb2"], p[f"{h}Thumb3"] = f"{h}Thumb1", f"{h}Thumb2"
    return p


#: Parent of each UPPER_BODY joint inside the 47-joint set (BEAT hierarchy); Spine is the root.
UPPER_BODY_PARENT: dict[str, str | None] = {
    "Spine": None,
    "Neck": "Spine",
    "Neck1": "Neck",
    **_finger_parents("Right"),
    **_finger_parents("Left"),
}
assert set(UPPER_BODY_PARENT) == set(UPPER_BODY)


def parents_within(skel: Skeleton, names: Sequence[str] = UPPER_BODY) -> dict[str, str | None]:
    """Nearest ancestor of each of ``names`` in ``skel`` that is itself in ``names``."""
    inside = set(names)
    out: dict[str, str | None] = {}
    for n in names:
        p = int(skel.parents[skel.index(n)])
        while p >= 0 and skel.names[p] not in inside:
            p = int(skel.parents[p])
        out[n] = skel.names[p] if p >= 0 else None
    return out


def adjacency(names: Sequence[str], parent: dict[str, str | None] | None = None) -> np.ndarray:
    """Eq. 5.6: (J, J) 0/1 matrix, 1 for parent–child pairs inside ``names`` and the diagonal.

    ``parent`` maps each name to its parent (default :data:`UPPER_BODY_PARENT`); a
    parent outside ``names`` is replaced by its nearest ancestor inside them.
    """
    parent = UPPER_BODY_PARENT if parent is None else parent
    names = list(names)
    idx = {n: i for i, n in enumerate(names)}
    A = np.eye(len(names), dtype=np.float32)
    for n in names:
        p = parent.get(n)
        while p is not None and p not in idx:
            p = parent.get(p)
        if p is not None:
            A[idx[n], idx[p]] = A[idx[p], idx[n]] = 1.0
    return A


# ------------------------------------------------------------------------ config
@dataclass
class FGDConfig:
    """Every size and training setting of the FGD autoencoder (saved with it)."""

    window: int = 32  # frames per window (must be divisible by 4)
    stride: int = 10  # training window stride (frames)
    eval_stride: int = 10  # window stride when embedding motion for FGD
    hidden: int = 128  # latent size per latent time step ("hidden 128")
    channels: tuple[int, int] = (16, 32)  # per-joint channels c1, c2 of the graph layers (ours: CPU budget)
    lambda_pos: float = 1.0  # λ_r of eq. 5.4
    lambda_vel: float = 0.1  # λ_v of eq. 5.4
    batch_size: int = 256  # B
    lr_base: float = 1.2e-4  # lr = lr_base · B / 128 (eq. 5.5)
    momentum: float = 0.9  # not stated in the thesis; 0 = plain SGD
    epochs: int = 400
    seed: int = 0
    fps: float = float(MODEL_FPS)

    @property
    def lr(self) -> float:
        return self.lr_base * self.batch_size / 128.0

    def __post_init__(self) -> None:
        self.channels = tuple(int(c) for c in self.channels)  # type: ignore[assignment]
        if self.window % 4 or self.window < 4:
            raise ValueError(f"window must be a positive multiple of 4, got {self.window}")
        if self.stride < 1 or self.eval_stride < 1:
            raise ValueError("strides must be ≥ 1")


# ------------------------------------------------------------------------ model
class GraphConv(nn.Module):
    """Eq. 5.7 with a temporal kernel: ``tanh(Σ_j A_ij W h_j + b)``; x (B, C, T, J)."""

    def __init__(
        self, A: torch.Tensor, c_in: int, c_out: int, kernel: int = 3, stride: int = 1, activation: bool = True
    ):
        super().__init__()
        pad = (kernel - stride + 1) // 2 if stride > 1 else kernel // 2
        self.W = nn.Conv2d(c_in, c_out, (kernel, 1), stride=(stride, 1), padding=(pad, 0), bias=False)
        self.b = nn.Parameter(torch.zeros(c_out))
        self.register_buffer("A", A.clone(), persistent=False)
        self.activation = activation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.W(x)  # (B, C_out, T', J): W h_j for every joint
        h = torch.einsum("bctj,ij->bcti", h, self.A) + self.b[None, :, None, None]  # Σ_j A_ij (…) + b
        return torch.tanh(h) if self.activation else h


class FGDAutoencoder(nn.Module):
    """Skeleton-aware motion autoencoder over one joint set (see module docstring)."""

    def __init__(self, config: FGDConfig, joints: Sequence[str]):
        super().__init__()
        self.config, self.joints = config, list(joints)
        A = torch.from_numpy(adjacency(self.joints))
        J, (c1, c2), H = len(self.joints), config.channels, config.hidden
        self.enc = nn.ModuleList([GraphConv(A, 6, c1, 3), GraphConv(A, c1, c2, 4, 2), GraphConv(A, c2, c2, 4, 2)])
        self.to_latent = nn.Linear(J * c2, H)
        self.from_latent = nn.Linear(H, J * c2)
        self.dec = nn.ModuleList([GraphConv(A, c2, c1, 3), GraphConv(A, c1, c1, 3)])
        self.out = GraphConv(A, c1, 6, 3, activation=False)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Windows (B, T, J, 6) → latent sequence (B, T/4, hidden)."""
        h = x.permute(0, 3, 1, 2)  # (B, 6, T, J)
        for layer in self.enc:
            h = layer(h)  # (B, c, T', J)
        B, C, T4, J = h.shape
        return self.to_latent(h.permute(0, 2, 3, 1).reshape(B, T4, J * C))  # (B, T/4, H)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Latent sequence (B, T/4, hidden) → windows (B, T, J, 6)."""
        B, T4, _ = z.shape
        J, c2 = len(self.joints), self.config.channels[1]
        h = torch.tanh(self.from_latent(z)).reshape(B, T4, J, c2).permute(0, 3, 1, 2)  # (B, c2, T/4, J)
        for layer in self.dec:
            h = layer(torch.repeat_interleave(h, 2, dim=2))  # ×2 in time, then graph layer
        return self.out(h).permute(0, 2, 3, 1)  # (B, T, J, 6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))


def reconstruction_loss(
    pred: torch.Tensor, target: torch.Tensor, lambda_pos: float = 1.0, lambda_vel: float = 0.1
) -> torch.Tensor:
    """Eq. 5.4: λ_r·MSE(ĝ, g) + λ_v·MSE(ĝ′, g′), ′ = difference along the frame axis (dim 1)."""
    pos = torch.mean((pred - target) ** 2)
    vel = torch.mean((pred.diff(dim=1) - target.diff(dim=1)) ** 2)
    return lambda_pos * pos + lambda_vel * vel


# ----------------------------------------------------------------------- windows
def make_windows(clips: Iterable[np.ndarray], window: int = 32, stride: int = 10) -> np.ndarray:
    """Cut every clip (T, J, 6) into windows → (N, window, J, 6) float32.

    Window starts are 0, stride, 2·stride, … while a full window fits; shorter clips
    contribute nothing. Returns an empty (0, window, J, 6) array when nothing fits.
    """
    out, J = [], None
    for c in clips:
        c = np.asarray(c, dtype=np.float32)
        if c.ndim != 3 or c.shape[-1] != 6:
            raise ValueError(f"clips must be (T, J, 6) rot6d, got {c.shape}")
        J = c.shape[1]
        for s in range(0, c.shape[0] - window + 1, stride):
            out.append(c[s : s + window])
    if not out:
        return np.zeros((0, window, J or N_JOINTS, 6), np.float32)
    return np.stack(out)


# ----------------------------------------------------------------- Fréchet distance
def gaussian_stats(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and covariance (D, D) of samples (N, D), float64 (covariance 0 for N = 1)."""
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2 or f.shape[0] == 0:
        raise ValueError(f"features must be (N ≥ 1, D), got {f.shape}")
    mu = f.mean(0)
    cov = np.cov(f, rowvar=False) if f.shape[0] > 1 else np.zeros((f.shape[1], f.shape[1]))
    return mu, np.atleast_2d(cov)


def _psd_sqrt(S: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh((S + S.T) / 2)
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


def _trace_sqrt_product_eigh(s1: np.ndarray, s2: np.ndarray) -> float:
    r1 = _psd_sqrt(s1)
    M = r1 @ s2 @ r1
    w = np.linalg.eigvalsh((M + M.T) / 2)
    return float(np.sqrt(np.clip(w, 0.0, None)).sum())


def _trace_sqrt_product_sqrtm(s1: np.ndarray, s2: np.ndarray, eps: float) -> float | None:
    import warnings

    from scipy import linalg

    with warnings.catch_warnings():  # singular products are expected; the result is checked below
        warnings.simplefilter("ignore", linalg.LinAlgWarning)
        covmean = linalg.sqrtm(s1 @ s2)
        if not np.all(np.isfinite(covmean)):
            off = np.eye(s1.shape[0]) * eps
            covmean = linalg.sqrtm((s1 + off) @ (s2 + off))
    if not np.all(np.isfinite(covmean)):
        return None
    if np.iscomplexobj(covmean):
        if np.max(np.abs(np.imag(np.diagonal(covmean)))) > 1e-3:
            return None
        covmean = np.real(covmean)
    return float(np.trace(covmean))


def frechet_distance(
    mu1: np.ndarray, sigma1: np.ndarray, mu2: np.ndarray, sigma2: np.ndarray, method: str = "eigh", eps: float = 1e-6
) -> float:
    """Eq. 5.3 between N(μ1, Σ1) and N(μ2, Σ2): a finite real number ≥ 0.

    ``method="eigh"`` (default) uses the symmetric form Σ1^{1/2} Σ2 Σ1^{1/2}; ``"sqrtm"``
    uses scipy's ``sqrtm`` of Σ1 Σ2 (ε·I retry, tiny imaginary parts dropped) and falls
    back to ``"eigh"`` when the result is not usable. Round-off below zero is clipped.
    """
    mu1, mu2 = np.atleast_1d(np.asarray(mu1, np.float64)), np.atleast_1d(np.asarray(mu2, np.float64))
    s1, s2 = np.atleast_2d(np.asarray(sigma1, np.float64)), np.atleast_2d(np.asarray(sigma2, np.float64))
    if mu1.shape != mu2.shape or s1.shape != s2.shape or s1.shape != (mu1.size, mu1.size):
        raise ValueError(f"shape mismatch: μ {mu1.shape} vs {mu2.shape}, Σ {s1.shape} vs {s2.shape}")
    if method not in ("eigh", "sqrtm"):
        raise ValueError(f"method must be 'eigh' or 'sqrtm', got {method!r}")
    tr = None
    if method == "sqrtm":
        tr = _trace_sqrt_product_sqrtm(s1, s2, eps)
    if tr is None:
        tr = _trace_sqrt_product_eigh(s1, s2)
    diff = mu1 - mu2
    d = float(diff @ diff + np.trace(s1) + np.trace(s2) - 2.0 * tr)
    return max(d, 0.0)


def frechet_distance_features(real: np.ndarray, generated: np.ndarray, method: str = "eigh") -> float:
    """Eq. 5.3 between the Gaussians fitted to two feature sets (N, D) and (M, D)."""
    return frechet_distance(*gaussian_stats(real), *gaussian_stats(generated), method=method)


# ---------------------------------------------------------------- the evaluator
@dataclass
class TrainHistory:
    """Mean training loss per epoch for each region."""

    loss: dict[str, list[float]] = field(default_factory=dict)
    n_windows: int = 0


class FGDEvaluator:
    """One trained :class:`FGDAutoencoder` per evaluation region; embeds and scores motion."""

    def __init__(self, config: FGDConfig, models: dict[str, FGDAutoencoder], history: TrainHistory | None = None):
        self.config, self.models = config, models
        self.history = history or TrainHistory()

    @property
    def regions(self) -> list[str]:
        return list(self.models)

    @torch.no_grad()
    def embed(self, clips: Sequence[np.ndarray], region: str, batch: int = 512) -> np.ndarray:
        """Latent samples (N·window/4, hidden) of clips of 47-joint poses (T, 47, 6)."""
        model = self._model(region)
        idx = region_indices(region)
        wins = make_windows([np.asarray(c)[:, idx] for c in clips], self.config.window, self.config.eval_stride)
        if len(wins) == 0:
            raise ValueError(f"no clip has the {self.config.window} frames one FGD window needs")
        model.eval()
        z = [model.encode(torch.from_numpy(wins[i : i + batch])) for i in range(0, len(wins), batch)]
        return torch.cat(z).reshape(-1, self.config.hidden).numpy().astype(np.float64)

    def fgd(
        self, real: Sequence[np.ndarray], generated: Sequence[np.ndarray], region: str, method: str = "eigh"
    ) -> float:
        """FGD (eq. 5.3) between real and generated clips (lists of (T, 47, 6)) in ``region``."""
        return frechet_distance_features(self.embed(real, region), self.embed(generated, region), method)

    def _model(self, region: str) -> FGDAutoencoder:
        if region not in self.models:
            raise KeyError(f"this FGD evaluator has no autoencoder for region {region!r} (has {self.regions})")
        return self.models[region]


def train_fgd(
    clips: Sequence[np.ndarray],
    config: FGDConfig | None = None,
    regions: Sequence[str] = REGIONS,
    progress: bool = True,
) -> FGDEvaluator:
    """Train one autoencoder per region on clips of poses (T, 47, 6) (eq. 5.4–5.5)."""
    config = config or FGDConfig()
    clips = [np.asarray(c, np.float32) for c in clips]
    for c in clips:
        if c.ndim != 3 or c.shape[1:] != (N_JOINTS, 6):
            raise ValueError(f"clips must be (T, {N_JOINTS}, 6) rot6d poses, got {c.shape}")
    windows = make_windows(clips, config.window, config.stride)
    if len(windows) == 0:
        raise ValueError(f"no clip has the {config.window} frames one FGD window needs")
    history = TrainHistory(n_windows=len(windows))
    models: dict[str, FGDAutoencoder] = {}
    from rich.progress import BarColumn, TextColumn, TimeRemainingColumn

    from facecapges.progress import Progress

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeRemainingColumn(),
        disable=not progress,
        transient=False,
    ) as bar:
        for region in regions:
            task = bar.add_task(f"FGD autoencoder [{region}]", total=config.epochs)
            torch.manual_seed(config.seed)
            rng = np.random.default_rng(config.seed)
            model = FGDAutoencoder(config, region_joints(region))
            data = torch.from_numpy(windows[:, :, region_indices(region)])
            opt = torch.optim.SGD(model.parameters(), lr=config.lr, momentum=config.momentum)
            losses: list[float] = []
            for _epoch in range(config.epochs):
                model.train()
                order = rng.permutation(len(data))
                total = 0.0
                for s in range(0, len(order), config.batch_size):
                    x = data[order[s : s + config.batch_size]]
                    loss = reconstruction_loss(model(x), x, config.lambda_pos, config.lambda_vel)
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    total += float(loss.detach()) * len(x)
                losses.append(total / len(order))
                bar.update(task, advance=1, description=f"FGD autoencoder [{region}] loss {losses[-1]:.4f}")
            model.eval()
            models[region], history.loss[region] = model, losses
    return FGDEvaluator(config, models, history)


# --------------------------------------------------------------------- save/load
def fgd_paths(location: str | Path) -> tuple[Path, Path]:
    """(weights, config) paths for a directory or next to a checkpoint file (see module doc)."""
    p = Path(location)
    if p.suffix == ".safetensors" and not p.is_dir():
        p = p.with_name(f"{p.stem}.fgd")
    return p / FGD_WEIGHTS, p / FGD_CONFIG


PACKAGED_FGD = "beat-upper-body"


def packaged_fgd_dir() -> Path:
    """The FGD autoencoder that ships with the package (module docstring)."""
    return Path(__file__).resolve().parents[1] / "assets" / "fgd" / PACKAGED_FGD


def find_fgd(checkpoint: str | Path | None, given: str | Path | None = None) -> tuple[Path | None, str]:
    """(location, what it is) of the autoencoder to score ``checkpoint`` with: ``given``, else the
    checkpoint's own, else the packaged one; (None, why) when there is none."""
    if given is not None:
        return Path(given), "given with --fgd"
    if checkpoint is not None and fgd_paths(checkpoint)[1].exists():
        return Path(checkpoint), "the style's own"
    if fgd_paths(packaged_fgd_dir())[1].exists():
        return packaged_fgd_dir(), f"the package's {PACKAGED_FGD} (BEAT speaker 2's training frames)"
    return None, f"none next to {checkpoint} and no packaged {PACKAGED_FGD}"


def save_fgd(evaluator: FGDEvaluator, location: str | Path) -> tuple[Path, Path]:
    """Write the weights and the JSON document (:func:`fgd_paths`); returns both paths."""
    from safetensors.torch import save_file

    w_path, cfg_path = fgd_paths(location)
    w_path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {
        f"{r}.{k}": v.detach().contiguous() for r, m in evaluator.models.items() for k, v in m.state_dict().items()
    }
    save_file(tensors, str(w_path))
    meta = {
        "config": asdict(evaluator.config),
        "regions": {r: m.joints for r, m in evaluator.models.items()},
        "history": {"loss": evaluator.history.loss, "n_windows": evaluator.history.n_windows},
        "format": "facecapges-fgd-autoencoder/1",
    }
    cfg_path.write_text(json.dumps(meta, indent=1))
    return w_path, cfg_path


def load_fgd(location: str | Path) -> FGDEvaluator:
    """Read what :func:`save_fgd` wrote; raises UserError naming the file on any problem."""
    from safetensors.torch import load_file

    from facecapges.errors import file_error, require_file

    w_guess, cfg_guess = fgd_paths(location)
    cfg_path = require_file(cfg_guess, "FGD autoencoder config")
    w_path = require_file(w_guess, "FGD autoencoder weights")
    try:
        meta = json.loads(cfg_path.read_text())
        config = FGDConfig(**meta["config"])
        tensors = load_file(str(w_path))
    except (ValueError, KeyError, TypeError, OSError) as exc:
        raise file_error(cfg_path, f"not a readable FGD autoencoder ({exc})") from None
    models = {}
    for region, joints in meta["regions"].items():
        m = FGDAutoencoder(config, joints)
        prefix = f"{region}."
        state = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
        try:
            m.load_state_dict(state)
        except RuntimeError as exc:
            raise file_error(w_path, f"weights do not match the config for region {region!r}: {exc}") from None
        models[region] = m.eval()
    hist = meta.get("history", {})
    return FGDEvaluator(config, models, TrainHistory(hist.get("loss", {}), hist.get("n_windows", 0)))


__all__ = [
    "UPPER_BODY_PARENT",
    "FGDAutoencoder",
    "FGDConfig",
    "FGDEvaluator",
    "GraphConv",
    "adjacency",
    "fgd_paths",
    "find_fgd",
    "frechet_distance",
    "frechet_distance_features",
    "gaussian_stats",
    "load_fgd",
    "make_windows",
    "packaged_fgd_dir",
    "parents_within",
    "reconstruction_loss",
    "save_fgd",
    "train_fgd",
]
