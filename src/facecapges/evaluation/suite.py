"""All metrics for several methods, in both regions — the API ``facecapges eval`` calls.

:func:`evaluate_paired` scores methods whose output is aligned frame by frame with a
real held-out motion (the same speech): FGD (against the real motion, or a larger
real reference set), SRGR, BeatAlign with its shifted-audio control and L1DIV.
:func:`evaluate_unpaired` scores motion generated for audio that has no real motion
(unseen speech): BeatAlign (+ control), L1DIV and FGD against the speaker's real
distribution.

A method is given as one (T, 47, 6) array or a list of such arrays — several samples
for the same input (seeds, initial poses). Per-sequence metrics (SRGR, BA, L1DIV
temporal) are averaged over samples; FGD pools every sample's windows; eq. 5.11
(``L1DIV_samples``) needs ≥ 2 samples and is ``None`` otherwise.

Result layout (JSON-able dict)::

    {"fps", "sr", "n_frames", "sigma_s", "srgr_delta", "srgr_weighted", "ba_mode",
     "ba_offsets_s", "paired",
     "regions": {region: {"joints": [...],
                          "methods": {name: {"FGD", "SRGR", "BA", "BA_shifted_mean",
                                             "BA_shifted_sd", "BA_gap", "BA_gap_sd", "L1DIV",
                                             "L1DIV_samples", "n_samples"}}}},
     "synchrony": {"methods": {name: {"ES_r", "ES_shifted_mean", "ES_shifted_sd", "ES_z", "jerk",
                                      "spread", "jerk_ratio", "spread_ratio", "n_frames"}},
                   "reference": {"jerk", "spread", "source"}}}

FGD is ``None`` when no FGD autoencoder (or none for that region) is given. The
``synchrony`` section (:mod:`facecapges.evaluation.synchrony`: energy–speed
correlation with its shifted-audio z-score, wrist jerk and spread and their ratios to
the real motion) is present when a ``skeleton`` is given (wrist positions need forward
kinematics); ``BA_gap_sd`` is the BeatAlign gap in shifted-sd units. With a skeleton
the ``peers`` section also holds each method's BA, SRGR and L1div as BEAT/CaMN's and
EMAGE's scripts compute them (:mod:`facecapges.evaluation.peers`, all 47 joints, no
regions): ``{"methods": {name: {"BA_BEAT", "BA_BEAT_true_times", "BA_EMAGE",
"SRGR_BEAT", "L1DIV_BEAT"}}, "n_speech_beats": {...}}``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from facecapges.evaluation import beat_align as ba
from facecapges.evaluation import synchrony as sy
from facecapges.evaluation.fgd import FGDEvaluator
from facecapges.evaluation.l1div import l1div_samples, l1div_temporal
from facecapges.evaluation.regions import REGIONS, region_joints, select
from facecapges.evaluation.srgr import DELTA, srgr
from facecapges.skeleton import N_JOINTS

Method = np.ndarray | Sequence[np.ndarray]
DEFAULT_OFFSETS_S = tuple(float(x) for x in range(2, 61, 2))


def _samples(name: str, m: Method, n_frames: int | None) -> list[np.ndarray]:
    arrs = (
        [np.asarray(m, np.float32)]
        if isinstance(m, np.ndarray) and np.asarray(m).ndim == 3
        else [np.asarray(x, np.float32) for x in m]
    )
    for a in arrs:
        if a.ndim != 3 or a.shape[1:] != (N_JOINTS, 6):
            raise ValueError(f"method {name!r}: poses must be (T, {N_JOINTS}, 6), got {a.shape}")
        if n_frames is not None and len(a) != n_frames:
            raise ValueError(f"method {name!r}: {len(a)} frames, the real motion has {n_frames}")
    if not arrs:
        raise ValueError(f"method {name!r} has no samples")
    return arrs


def _progress(total: int, enabled: bool, what: str):
    from facecapges.progress import Progress

    bar = Progress(disable=not enabled, transient=True)
    return bar, bar.add_task(what, total=total)


def _score_method(
    samples: list[np.ndarray],
    region: str,
    audio: np.ndarray,
    sr: int,
    fps: float,
    real: np.ndarray | None,
    weights: np.ndarray | None,
    fgd: FGDEvaluator | None,
    fgd_reference: Sequence[np.ndarray] | None,
    offsets_s: Sequence[float],
    sigma_s: float,
    ba_mode: str,
    speech_sets,
) -> dict:
    reg = [select(s, region) for s in samples]
    out: dict = {"n_samples": len(samples)}
    if fgd is not None and region in fgd.models and fgd_reference:
        out["FGD"] = fgd.fgd(list(fgd_reference), samples, region)
    else:
        out["FGD"] = None
    out["SRGR"] = (
        float(np.mean([srgr(select(real, region), r, weights).value for r in reg])) if real is not None else None
    )
    controls = [
        ba.beat_align_control(r, audio, sr, fps, offsets_s, sigma_s, mode=ba_mode, speech=speech_sets(len(r)))
        for r in reg
    ]
    out["BA"] = float(np.mean([c.matched for c in controls]))
    out["BA_shifted_mean"] = float(np.mean([c.shifted_mean for c in controls]))
    out["BA_shifted_sd"] = float(np.mean([c.shifted_sd for c in controls]))
    out["BA_gap"] = out["BA"] - out["BA_shifted_mean"]
    gsd = [sy.beat_align_gap_sd(c) for c in controls]
    out["BA_gap_sd"] = float(np.mean(gsd)) if all(np.isfinite(gsd)) else None
    out["L1DIV"] = float(np.mean([l1div_temporal(r) for r in reg]))
    same_len = len({len(r) for r in reg}) == 1
    out["L1DIV_samples"] = l1div_samples(reg) if len(reg) >= 2 and same_len else None
    return out


def _result_head(fps, sr, n, sigma_s, weighted: bool, ba_mode: str, offsets_s, paired: bool) -> dict[str, Any]:
    """The settings a suite result starts with (its regions filled in by :func:`_evaluate`)."""
    return {
        "fps": fps,
        "sr": sr,
        "n_frames": n,
        "sigma_s": sigma_s,
        "srgr_delta": DELTA,
        "srgr_weighted": weighted,
        "ba_mode": ba_mode,
        "ba_offsets_s": [float(o) for o in offsets_s],
        "paired": paired,
        "regions": {},
    }


def _evaluate(
    methods: Mapping[str, Method],
    audio: np.ndarray,
    sr: int,
    fps: float,
    real: np.ndarray | None,
    fgd: FGDEvaluator | None,
    fgd_reference: Sequence[np.ndarray] | None,
    semantic_weights: np.ndarray | None,
    regions: Sequence[str],
    offsets_s: Sequence[float],
    sigma_s: float,
    ba_mode: str,
    progress: bool,
    skeleton=None,
    real_stats: sy.MotionStats | None = None,
) -> dict:
    n = len(real) if real is not None else None
    samples = {k: _samples(k, v, n) for k, v in methods.items()}
    if n is None:
        n = len(next(iter(samples.values()))[0]) if samples else 0
    result = _result_head(fps, sr, n, sigma_s, semantic_weights is not None, ba_mode, offsets_s, real is not None)
    cache: dict[int, ba.SpeechBeatSets] = {}

    def speech_sets(n_frames: int) -> ba.SpeechBeatSets:  # onsets once per audio length, shared by all rows
        if n_frames not in cache:
            cache[n_frames] = ba.speech_beat_sets(audio, sr, n_frames, fps, offsets_s)
        return cache[n_frames]

    bar, task = _progress(len(regions) * len(samples), progress, "evaluating")
    with bar:
        for region in regions:
            rows = {}
            for name, s in samples.items():
                bar.update(task, description=f"evaluating {name} [{region}]")
                rows[name] = _score_method(
                    s,
                    region,
                    audio,
                    sr,
                    fps,
                    real,
                    semantic_weights,
                    fgd,
                    fgd_reference,
                    offsets_s,
                    sigma_s,
                    ba_mode,
                    speech_sets,
                )
                bar.advance(task)
            result["regions"][region] = {"joints": list(region_joints(region)), "methods": rows}
    if skeleton is not None:
        result.update(
            _skeleton_metrics(samples, skeleton, audio, sr, fps, real, real_stats, offsets_s, semantic_weights)
        )
    return result


def _skeleton_metrics(
    samples: Mapping[str, list[np.ndarray]],
    skeleton,
    audio: np.ndarray,
    sr: int,
    fps: float,
    real: np.ndarray | None,
    real_stats: sy.MotionStats | None,
    offsets_s: Sequence[float],
    weights: np.ndarray | None,
) -> dict:
    """The metrics that need joint positions, per method (mean over samples), on all 47 joints.

    ``"synchrony"``: :func:`facecapges.evaluation.synchrony.synchrony_row`; jerk/spread ratios are to
    the real motion (paired) or to ``real_stats`` (unpaired), ``"reference"`` records those
    reference figures. ``"peers"``: :func:`facecapges.evaluation.peers.peer_metrics`."""
    from facecapges.evaluation import peers

    if real is not None:
        ref = sy.motion_stats(sy.wrist_positions(skeleton, real), fps)
    else:
        ref = real_stats
    n = len(next(iter(samples.values()))[0]) if samples else 0
    a = ba.fit_audio(audio, n, fps, sr)
    speech = peers.peer_speech(a, sr)
    reference = {
        "jerk": ref.jerk if ref else None,
        "spread": ref.spread if ref else None,
        "source": "the real motion" if real is not None else "the speaker's real clips",
    }
    sync = _mean_rows(
        samples, lambda x: sy.synchrony_row(sy.wrist_positions(skeleton, x), audio, sr, fps, ref, offsets_s)
    )
    peer = _mean_rows(samples, lambda x: peers.peer_metrics(real, x, a, sr, fps, skeleton, weights, speech))
    return {
        "synchrony": {"methods": sync, "reference": reference},
        "peers": {"methods": peer, "n_speech_beats": {k: int(len(v)) for k, v in speech.items()}},
    }


def _mean_rows(samples: Mapping[str, list[np.ndarray]], row) -> dict:
    """Per method, each figure of ``row(sample)`` averaged over the method's samples (:func:`_finite_mean`)."""
    methods = {}
    for name, arrs in samples.items():
        rows = [row(x) for x in arrs]
        methods[name] = {k: _finite_mean([r[k] for r in rows]) for k in rows[0]}
    return methods


def _finite_mean(vals) -> float | None:
    ok = [float(v) for v in vals if v is not None and np.isfinite(v)]
    return float(np.mean(ok)) if ok and len(ok) == len(vals) else None


def evaluate_paired(
    real: np.ndarray,
    methods: Mapping[str, Method],
    audio: np.ndarray,
    sr: int,
    fps: float,
    fgd: FGDEvaluator | None = None,
    fgd_reference: Sequence[np.ndarray] | None = None,
    semantic_weights: np.ndarray | None = None,
    regions: Sequence[str] = REGIONS,
    offsets_s: Sequence[float] = DEFAULT_OFFSETS_S,
    sigma_s: float = ba.SIGMA_S,
    ba_mode: str = "mean",
    progress: bool = True,
    skeleton=None,
) -> dict:
    """Every metric for each method against the real motion ``real`` (T, 47, 6) and its audio.

    ``fgd_reference`` defaults to ``[real]``; include a ``"ground truth"`` entry in
    ``methods`` (e.g. :func:`facecapges.evaluation.baselines.ground_truth`) for its row.
    """
    real = np.asarray(real, np.float32)
    if real.ndim != 3 or real.shape[1:] != (N_JOINTS, 6):
        raise ValueError(f"real must be (T, {N_JOINTS}, 6), got {real.shape}")
    ref = list(fgd_reference) if fgd_reference is not None else [real]
    return _evaluate(
        methods,
        audio,
        sr,
        fps,
        real,
        fgd,
        ref,
        semantic_weights,
        regions,
        offsets_s,
        sigma_s,
        ba_mode,
        progress,
        skeleton,
    )


def evaluate_unpaired(
    methods: Mapping[str, Method],
    audio: np.ndarray,
    sr: int,
    fps: float,
    fgd: FGDEvaluator | None = None,
    fgd_reference: Sequence[np.ndarray] | None = None,
    regions: Sequence[str] = REGIONS,
    offsets_s: Sequence[float] = DEFAULT_OFFSETS_S,
    sigma_s: float = ba.SIGMA_S,
    ba_mode: str = "mean",
    progress: bool = True,
    skeleton=None,
    real_reference: Sequence[np.ndarray] | None = None,
) -> dict:
    """BeatAlign (+ control), L1DIV and FGD vs ``fgd_reference`` for motion without real counterpart.

    With ``skeleton``, the synchrony section's jerk/spread ratios are to ``real_reference``
    (default ``fgd_reference``): the speaker's real clips, frame-weighted.
    """
    stats = None
    if skeleton is not None:
        ref = real_reference if real_reference is not None else fgd_reference
        stats = sy.pooled_stats([sy.motion_stats(sy.wrist_positions(skeleton, r), fps) for r in ref or []])
    return _evaluate(
        methods,
        audio,
        sr,
        fps,
        None,
        fgd,
        fgd_reference,
        None,
        regions,
        offsets_s,
        sigma_s,
        ba_mode,
        progress,
        skeleton,
        stats,
    )


_AVERAGED = ("SRGR", "BA", "BA_shifted_mean", "BA_shifted_sd", "BA_gap_sd", "L1DIV", "L1DIV_samples")
_SYNC_AVERAGED = ("ES_r", "ES_shifted_mean", "ES_shifted_sd", "ES_z", "jerk", "spread", "jerk_ratio", "spread_ratio")


def _weighted(vals, n) -> float | None:
    ok = [(v, w) for v, w in zip(vals, n) if v is not None and np.isfinite(v)]
    return float(sum(v * w for v, w in ok) / sum(w for _, w in ok)) if ok else None


def _combine_row(results, region: str, name: str, n: np.ndarray, fgd, fgd_reference, method_clips) -> dict:
    """One method's row of one region over clips (:func:`combine_clips`)."""
    per = [r["regions"][region]["methods"][name] for r in results]
    row = {"n_samples": per[0]["n_samples"]}
    for k in _AVERAGED:
        row[k] = _weighted([p.get(k) for p in per], n)
    row["BA_gap"] = row["BA"] - row["BA_shifted_mean"] if None not in (row["BA"], row["BA_shifted_mean"]) else None
    if fgd is not None and region in fgd.models and fgd_reference and method_clips and name in method_clips:
        row["FGD"] = fgd.fgd(list(fgd_reference), list(method_clips[name]), region)
    else:
        fg = [p["FGD"] for p in per]
        row["FGD"] = fg[0] if len(per) == 1 else None
    keys = ("FGD", "SRGR", "BA", "BA_shifted_mean", "BA_shifted_sd", "BA_gap", "BA_gap_sd", "L1DIV", "L1DIV_samples")
    return {k: row[k] for k in (*keys, "n_samples")}


def _combine_peers(results, n: np.ndarray) -> dict:
    """The peers section over clips: frame-weighted means, speech beats summed."""
    methods = {}
    for name, first in results[0]["peers"]["methods"].items():
        methods[name] = {k: _weighted([r["peers"]["methods"][name][k] for r in results], n) for k in first}
    return {
        "methods": methods,
        "n_speech_beats": {
            k: int(sum(r["peers"]["n_speech_beats"][k] for r in results)) for k in results[0]["peers"]["n_speech_beats"]
        },
    }


def _combine_synchrony(results, n: np.ndarray) -> dict:
    """The synchrony section over clips: each figure's frame-weighted mean."""
    methods = {}
    for name in results[0]["synchrony"]["methods"]:
        per = [r["synchrony"]["methods"][name] for r in results]
        methods[name] = {k: _weighted([p[k] for p in per], n) for k in _SYNC_AVERAGED}
        methods[name]["n_frames"] = int(n.sum())
    refs = [r["synchrony"]["reference"] for r in results]
    return {
        "methods": methods,
        "reference": {
            "jerk": _weighted([x["jerk"] for x in refs], n),
            "spread": _weighted([x["spread"] for x in refs], n),
            "source": refs[0]["source"],
        },
    }


def combine_clips(
    results: Sequence[dict],
    fgd: FGDEvaluator | None = None,
    fgd_reference: Sequence[np.ndarray] | None = None,
    method_clips: Mapping[str, Sequence[np.ndarray]] | None = None,
) -> dict:
    """Merge per-clip results of the same methods into one (several held-out clips).

    SRGR, BA (matched, shifted mean and sd, gap in sd units), L1DIV and every figure of
    the synchrony section (each clip's own r, z and ratios) are averaged over clips
    weighted by their frame counts; the BA gap is recomputed from the averages. FGD is not an
    average: with ``fgd``, ``fgd_reference`` (all real clips) and ``method_clips``
    (each method's clips) it is computed once over the pooled windows of all clips.
    """
    if not results:
        raise ValueError("no per-clip results to combine")
    n = np.array([r["n_frames"] for r in results], np.float64)
    out = {k: v for k, v in results[0].items() if k != "regions"}
    out["n_frames"] = int(n.sum())
    out["n_clips"] = len(results)
    out["regions"] = {}
    for region, reg in results[0]["regions"].items():
        rows = {
            name: _combine_row(results, region, name, n, fgd, fgd_reference, method_clips) for name in reg["methods"]
        }
        out["regions"][region] = {"joints": reg["joints"], "methods": rows}
    if all("peers" in r for r in results):
        out["peers"] = _combine_peers(results, n)
    if all("synchrony" in r for r in results):
        out["synchrony"] = _combine_synchrony(results, n)
    return out


@dataclass
class PairedClips:
    """The suite over several held-out clips: :meth:`add` scores one (:func:`evaluate_paired`, FGD left
    out), :meth:`combine` pools them (:func:`combine_clips`, FGD over every clip's windows)."""

    sr: int
    fps: float
    offsets_s: Sequence[float] = DEFAULT_OFFSETS_S
    progress: bool = True
    per_clip: list[dict] = field(default_factory=list)
    real_clips: list[np.ndarray] = field(default_factory=list)
    method_clips: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def add(self, real: np.ndarray, methods: Mapping[str, Method], audio: np.ndarray, semantic_weights, skeleton):
        """Score one clip's ``methods`` against its ``real`` motion; keep their sequences for FGD."""
        self.per_clip.append(
            evaluate_paired(
                real,
                methods,
                audio,
                self.sr,
                self.fps,
                fgd=None,
                semantic_weights=semantic_weights,
                offsets_s=self.offsets_s,
                progress=self.progress,
                skeleton=skeleton,
            )
        )
        self.real_clips.append(real)
        for k, m in methods.items():
            self.method_clips.setdefault(k, []).extend([m] if isinstance(m, np.ndarray) else m)

    def combine(self, fgd: FGDEvaluator | None) -> dict:
        """Every clip's results in one (:func:`combine_clips`)."""
        return combine_clips(self.per_clip, fgd, self.real_clips, self.method_clips)
