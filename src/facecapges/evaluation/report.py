"""Writing an evaluation: ``metrics.json``, the Table 5.2 Markdown table and PNG plots.

* :func:`markdown_table` — thesis Table 5.2's layout (region | method | FGD↓ | SRGR↑ |
  BA↑ | L1DIV↑), both regions, followed by the BeatAlign control table (matched,
  shifted mean ± sd, gap) and notes stating each metric's definition and units.
* :func:`plot_beat_timeline` — speech beats vs motion beats on one clip: audio
  waveform with onset strength and speech beats on top, mean joint angular speed
  with motion beats below, one row per motion (e.g. real and generated).
* :func:`plot_speed_distributions` — histograms (density) of per-joint angular speed
  (rad/s), real vs each generated motion.
* :func:`markdown_unseen_table` — BeatAlign (+ control), L1DIV and FGD of motion
  generated for unseen audio.
* :func:`realism_lines` — issue #25 §3's figures beside their targets (✓/✗), with the
  realism section's notes (:mod:`facecapges.evaluation.realism`).
* :func:`write_report` — all of the above into one directory.

The side-by-side skeleton video lives in :mod:`facecapges.avatar.render.skeleton_video`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from facecapges.evaluation import beat_align as ba
from facecapges.evaluation.regions import REGION_TITLES, REGIONS, select


def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    return f"{v:.{digits}f}"


def _definitions(result: dict) -> list[str]:
    """The definitions under :func:`markdown_table`."""
    offs = result.get("ba_offsets_s") or []
    return [
        "",
        "Definitions:",
        "- FGD (eq. 5.3): Fréchet distance between Gaussians fitted to the latent features of the "
        "skeleton-aware autoencoder (one per region); lower is closer to the real distribution.",
        f"- SRGR (eq. 5.8): share of joint-frames whose rot6d L1 error is below {result.get('srgr_delta', 0.5)}"
        + (
            ", weighted by the BEAT semantic score of the frame."
            if result.get("srgr_weighted")
            else "; no semantic file, so every frame has weight 1 (unweighted)."
        ),
        f"- BA (eq. 5.9–5.10): mean over speech beats of exp(−Δt²/2σ²), σ = {result.get('sigma_s', 0.3)} s; "
        f"motion beats = local minima of the {result.get('ba_mode', 'mean')} joint angular speed "
        "(mode 'mean': the region's mean speed curve; BEAT/CaMN's script scores one joint, EMAGE averages "
        "per-joint scores — see the peers' table). "
        f"Shifted: the audio rolled by {len(offs)} offsets "
        + (f"({offs[0]:g}–{offs[-1]:g} s)" if offs else "")
        + "; the gap, not the raw BA, shows synchrony.",
        "- L1DIV: per-sequence deviation from the temporal mean, Σ over the region's joints × 6 rot6d "
        "components of |r − mean_t r|, averaged over frames (BEAT/CaMN's L1div formula, but on rot6d: their "
        "code runs it on Euler degrees, hundreds times larger).",
        "- Regions (thesis 5.5.5): 'without head' drops Neck and Neck1 (the head-carrying joints).",
        f"- {result.get('n_frames')} frames at {result.get('fps')} fps.",
    ]


def markdown_table(result: dict, title: str = "Quantitative evaluation") -> str:
    """Table 5.2 layout for both regions, the BeatAlign control and definitions."""
    srgr_h = "SRGR↑" if result.get("srgr_weighted") else "SRGR (unweighted)↑"
    lines = [f"## {title}", "", f"| Region | Method | FGD↓ | {srgr_h} | BA↑ | L1DIV↑ |", "|---|---|---|---|---|---|"]
    regions = [r for r in REGIONS if r in result["regions"]]
    for region in regions:
        for i, (name, m) in enumerate(result["regions"][region]["methods"].items()):
            label = REGION_TITLES[region] if i == 0 else ""
            lines.append(
                f"| {label} | {name} | {_fmt(m['FGD'])} | {_fmt(m['SRGR'])} | {_fmt(m['BA'])} | {_fmt(m['L1DIV'])} |"
            )
    lines += [
        "",
        "### BeatAlign control (same motion, its own audio shifted)",
        "",
        "| Region | Method | BA matched | BA shifted (mean ± sd) | gap |",
        "|---|---|---|---|---|",
    ]
    for region in regions:
        for i, (name, m) in enumerate(result["regions"][region]["methods"].items()):
            label = REGION_TITLES[region] if i == 0 else ""
            lines.append(
                f"| {label} | {name} | {_fmt(m['BA'])} | {_fmt(m['BA_shifted_mean'])} ± "
                f"{_fmt(m['BA_shifted_sd'])} | {_fmt(m['BA_gap'], 4)} |"
            )
    lines += synchrony_lines(result)
    lines += realism_lines(result)
    lines += peer_lines(result)
    if any(m.get("L1DIV_samples") is not None for r in regions for m in result["regions"][r]["methods"].values()):
        lines += [
            "",
            "### L1DIV across generated samples (eq. 5.11)",
            "",
            "| Region | Method | L1DIV (eq. 5.11) |",
            "|---|---|---|",
        ]
        for region in regions:
            for name, m in result["regions"][region]["methods"].items():
                if m.get("L1DIV_samples") is not None:
                    lines.append(f"| {REGION_TITLES[region]} | {name} | {_fmt(m['L1DIV_samples'])} |")
    lines += _definitions(result)
    return "\n".join(lines) + "\n"


def synchrony_lines(result: dict, audio_label: str | None = None) -> list[str]:
    """The synchrony-control table of a suite result (empty without a ``synchrony`` section)."""
    sync = result.get("synchrony")
    if not sync:
        return []
    ref = sync["reference"]
    lines = [
        "",
        "### Synchrony controls (same motion, its own audio shifted; wrists vs the real motion)",
        "",
        ("| Audio " if audio_label else "") + "| Method | energy–speed r | shifted r (mean ± sd) | z | "
        "BA gap (sd units, with head / without) | wrist jerk × real | wrist spread × real |",
        ("|---" if audio_label else "") + "|---|---|---|---|---|---|---|",
    ]
    for name, m in sync["methods"].items():
        gaps = [
            result["regions"][r]["methods"].get(name, {}).get("BA_gap_sd") for r in REGIONS if r in result["regions"]
        ]
        lines.append(
            (f"| {audio_label} " if audio_label else "")
            + f"| {name} | {_fmt(m['ES_r'])} | {_fmt(m['ES_shifted_mean'])} ± {_fmt(m['ES_shifted_sd'])} | "
            f"{_fmt(m['ES_z'], 2)} | {' / '.join(_fmt(g, 2) for g in gaps)} | {_fmt(m['jerk_ratio'], 2)} | "
            f"{_fmt(m['spread_ratio'], 2)} |"
        )
    lines += [
        "",
        f"Energy–speed: Pearson r of the per-frame audio RMS and the mean wrist speed, both smoothed over "
        f"0.5 s; z = (r − shifted mean) / shifted sd over the same audio shifts as BeatAlign. Judge a model "
        f"against its speaker's real figure (ground truth row), not against 0. Jerk and spread are ratios to "
        f"{ref['source']} (jerk {_fmt(ref['jerk'], 0)} units/s³, spread {_fmt(ref['spread'], 2)} units); "
        "1.0 moves like the real speaker.",
    ]
    return lines


def _mark(value, lo: float | None, hi: float | None) -> str:
    """✓ when ``value`` is within [lo, hi] (either may be open), ✗ outside, nothing when unknown."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    ok = (lo is None or value >= lo) and (hi is None or value <= hi)
    return " ✓" if ok else " ✗"


def target_rows(result: dict, name: str) -> list[tuple[str, str, str]]:
    """Issue #25 §3's figures of one method: (figure, value with ✓/✗, target) rows."""
    from facecapges.evaluation import realism as rl

    sync = (result.get("synchrony") or {}).get("methods", {}).get(name, {})
    real = (result.get("realism") or {}).get("methods", {}).get(name, {})
    gap = result.get("regions", {}).get("with_head", {}).get("methods", {}).get(name, {}).get("BA_gap_sd")
    lo, hi = rl.SILENCE_TARGET
    ctl = (result.get("realism") or {}).get("control", {}).get("classifier")
    rows = [
        ("wrist spread × real", sync.get("spread_ratio"), 2, (0.8, 1.25), "0.8–1.25"),
        ("wrist jerk × real", sync.get("jerk_ratio"), 2, (0.8, 1.25), "0.8–1.25"),
        ("BeatAlign gap vs shifted audio (sd, with head)", gap, 2, (1.0, None), "≥ +1"),
        ("energy–wrist-speed z", sync.get("ES_z"), 2, (3.0, None), "≥ 3 (ZEGGS speaker; BEAT scott's real motion ≈ 0)"),
        ("transitions a minute", real.get("transitions_per_min"), 2, (None, rl.TRANSITION_TARGET_PER_MIN), "≤ 1"),
        ("longest verbatim copy (s)", real.get("longest_copy_s"), 1, (None, None), "— (informative)"),
        ("share of the database used", real.get("database_share_used"), 3, (None, None), "— (informative)"),
        ("returns within 20 s, a minute", real.get("returns_per_min"), 2, (None, None), "— (informative)"),
        ("silence: spread in pauses / in speech", real.get("silence_ratio"), 2, (lo, hi), f"{lo:g}–{hi:g}"),
        (
            "real-vs-generated classifier accuracy",
            real.get("classifier"),
            2,
            (None, rl.CLASSIFIER_TARGET),
            f"≤ {rl.CLASSIFIER_TARGET:g} (0.5 = indistinguishable; control {_fmt(ctl, 2)})",
        ),
    ]
    out = [(fig, _fmt(v, d) + (_mark(v, *rng) if rng != (None, None) else ""), t) for fig, v, d, rng, t in rows]
    if real and not real.get("pause_s"):
        out[8] = (out[8][0], "— (no pause ≥ 0.5 s)", out[8][2])
    return out


def realism_lines(result: dict, audio_label: str | None = None) -> list[str]:
    """Issue #25 §3's table (every figure beside its target) and the realism table of each method."""
    section = result.get("realism")
    if not section:
        return []
    names = list(section["methods"])
    where = f" — {audio_label}" if audio_label else ""
    lines = ["", f"### Against the targets of issue #25 §3{where}", ""]
    lines += ["| Figure | Target | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    per = {n: target_rows(result, n) for n in names}
    for i, (fig, _, target) in enumerate(per[names[0]]):
        lines.append(f"| {fig} | {target} | " + " | ".join(per[n][i][1] for n in names) + " |")
    ctl, db = section["control"], section["database"]
    lines += [
        "",
        "✓ / ✗: the target reached or not (the reference rows show where the real motion itself stands). "
        f"Transitions: frames whose joint acceleration (all 47 joints) exceeds the real motion's 99.9th "
        f"percentile ({_fmt(section['transition_threshold'], 0)} rad/s², from {section.get('reference_source', 'the real motion')}). "
        f"Repetition against {db['source']}"
        + (f" ({db['frames']} frames)" if db["frames"] else "")
        + ": nearest database frame within half the database's median frame step counts as copied. "
        "Silence: wrist spread within pauses / within speech (energy VAD with 0.3 s hangover). "
        f"Classifier: logistic regression on {section['window_s']:g}-s windows, {section['folds']} contiguous "
        + (
            f"blocks as folds, balanced; its control (held-out real vs the speaker's training motion) scores "
            f"{_fmt(ctl['classifier'], 2)} ± {_fmt(ctl['classifier_sd'], 2)} over {ctl['classifier_windows']} "
            "windows a class — the figure means something only when the control is near 0.5 "
            if ctl["classifier"] is not None
            else "blocks as folds, balanced; no control (no other real motion of the speaker) — "
        )
        + "(`facecapges.evaluation.realism`). Sample 0 of each method.",
    ]
    return lines


def peer_lines(result: dict) -> list[str]:
    """BA, SRGR and L1div as the peers' scripts compute them (empty without a ``peers`` section)."""
    peers = result.get("peers")
    if not peers:
        return []
    lines = [
        "",
        "### The same motion under the peers' metric code (all 47 joints; for published numbers only)",
        "",
        "| Method | BA (BEAT script) | BA (BEAT, true beat times) | BA (EMAGE) | SRGR (BEAT, 4° Euler) | "
        "L1div (BEAT, Euler °) |",
        "|---|---|---|---|---|---|",
    ]
    for name, m in peers["methods"].items():
        lines.append(
            f"| {name} | {_fmt(m['BA_BEAT'])} | {_fmt(m['BA_BEAT_true_times'])} | {_fmt(m['BA_EMAGE'])} | "
            f"{_fmt(m['SRGR_BEAT'])} | {_fmt(m['L1DIV_BEAT'], 1)} |"
        )
    lines += [
        "",
        "BEAT/CaMN's BeatAlign scores one joint (RightHandRing2, where its channel slice lands on 47-joint "
        "arrays) against speech beats whose times its script scales by 16000/22050 = 0.726 (it assumes "
        "librosa's 22.05 kHz); EMAGE averages per-joint scores of position-speed minima. BEAT's SRGR counts "
        "a joint-frame when its three Euler angles are within 4° (L1); its L1div sums Euler-degree "
        "deviations. These are not the thesis's definitions the tables above use (see "
        "`facecapges.evaluation.peers`).",
    ]
    return lines


def markdown_unseen_table(unseen: dict) -> str:
    """Table of results on unseen audio: ``{audio path: evaluate_unpaired result}``."""
    lines = [
        "",
        "## Unseen audio (no real motion)",
        "",
        "| Audio | Region | Method | FGD↓ (vs speaker's real motion) | BA↑ | BA shifted (mean ± sd) | gap | L1DIV↑ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for path, res in unseen.items():
        for region, reg in res["regions"].items():
            for name, m in reg["methods"].items():
                lines.append(
                    f"| {Path(path).name} | {REGION_TITLES[region]} | {name} | {_fmt(m['FGD'])} | "
                    f"{_fmt(m['BA'])} | {_fmt(m['BA_shifted_mean'])} ± {_fmt(m['BA_shifted_sd'])} | "
                    f"{_fmt(m['BA_gap'], 4)} | {_fmt(m['L1DIV'])} |"
                )
    for path, res in unseen.items():
        lines += synchrony_lines(res, Path(path).name)
        lines += realism_lines(res, Path(path).name)
    return "\n".join(lines) + "\n"


def write_metrics_json(result: dict, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)

    def clean(o):
        if isinstance(o, float) and (math.isnan(o) or math.isinf(o)):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, np.generic):
            return clean(o.item())
        return o

    p.write_text(json.dumps(clean(result), indent=1))
    return p


def _agg():
    from facecapges.io.plots import pyplot

    return pyplot()


def plot_beat_timeline(
    motions: Mapping[str, np.ndarray],
    audio: np.ndarray,
    sr: int,
    fps: float,
    path: str | Path,
    region: str = "with_head",
    max_seconds: float = 20.0,
    start_s: float = 0.0,
    sigma_s: float = ba.SIGMA_S,
) -> Path:
    """PNG: speech beats vs motion beats for each motion (T, 47, 6) over one stretch of the clip."""
    import librosa

    plt = _agg()
    names = list(motions)
    n = len(next(iter(motions.values())))
    a = ba.fit_audio(audio, n, fps, sr)
    sb = ba.speech_beats(a, sr)
    t0, t1 = start_s, min(start_s + max_seconds, n / fps)
    fig, axes = plt.subplots(1 + len(names), 1, figsize=(12, 2.2 * (1 + len(names))), sharex=True)
    ax = axes[0]
    ts = np.arange(len(a)) / sr
    sel = (ts >= t0) & (ts <= t1)
    ax.plot(ts[sel][::8], a[sel][::8], color="0.7", lw=0.5, label="audio")
    oenv = librosa.onset.onset_strength(y=a, sr=sr, hop_length=ba.HOP_LENGTH)
    ot = librosa.times_like(oenv, sr=sr, hop_length=ba.HOP_LENGTH)
    ax2 = ax.twinx()
    ax2.plot(ot, oenv, color="tab:blue", lw=0.8, label="onset strength")
    ax2.set_yticks([])
    for t in sb[(sb >= t0) & (sb <= t1)]:
        ax.axvline(t, color="tab:red", lw=0.8)
    ax.set_title(f"speech beats (red, {len(sb)} in clip) — onset strength (blue)")
    for ax, name in zip(axes[1:], names):
        pose = select(motions[name], region)
        speed = ba.joint_angular_speed(pose, fps).mean(1)
        tm = (np.arange(len(speed)) + 0.5) / fps
        mb = ba.motion_beats(pose, fps)
        score = ba.beat_align_score(sb, mb, sigma_s)
        ax.plot(tm, speed, color="k", lw=0.8)
        for t in sb[(sb >= t0) & (sb <= t1)]:
            ax.axvline(t, color="tab:red", lw=0.6, alpha=0.5)
        keep = (mb >= t0) & (mb <= t1)
        ax.plot(mb[keep], np.interp(mb[keep], tm, speed), "v", color="tab:green", ms=5)
        ax.set_ylabel("rad/s")
        ax.set_title(f"{name}: mean joint angular speed, motion beats (green ▼); BA = {score:.3f}")
    axes[-1].set_xlim(t0, t1)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def plot_speed_distributions(
    real: np.ndarray, generated: Mapping[str, np.ndarray], fps: float, path: str | Path, region: str = "with_head"
) -> Path:
    """PNG: density histograms of per-joint angular speed (rad/s), real vs generated."""
    plt = _agg()
    rs = ba.joint_angular_speed(select(real, region), fps).ravel()
    hi = float(np.percentile(rs, 99.5)) if len(rs) else 1.0
    for g in generated.values():
        gs = ba.joint_angular_speed(select(g, region), fps).ravel()
        hi = max(hi, float(np.percentile(gs, 99.5)) if len(gs) else 0.0)
    bins = np.linspace(0, hi if hi > 0 else 1.0, 60)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.hist(
        np.clip(rs, 0, bins[-1]),
        bins=bins,
        density=True,
        histtype="stepfilled",
        alpha=0.35,
        color="k",
        label=f"real (mean {rs.mean():.2f})",
    )
    for name, g in generated.items():
        gs = ba.joint_angular_speed(select(g, region), fps).ravel()
        ax.hist(
            np.clip(gs, 0, bins[-1]),
            bins=bins,
            density=True,
            histtype="step",
            lw=1.5,
            label=f"{name} (mean {gs.mean():.2f})",
        )
    ax.set_xlabel("joint angular speed (rad/s)")
    ax.set_ylabel("density (log)")
    ax.set_yscale("log")
    ax.set_title(f"Joint speed distribution, {REGION_TITLES[region].lower()}")
    ax.legend()
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def write_report(
    out_dir: str | Path,
    result: dict,
    real: np.ndarray | None,
    generated: Mapping[str, np.ndarray],
    audio: np.ndarray,
    sr: int,
    fps: float,
    title: str = "Quantitative evaluation",
    timeline_methods: Sequence[str] | None = None,
) -> dict:
    """metrics.json, metrics.md, beat_timeline.png and joint_speed.png in ``out_dir``; returns their paths."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    paths = {"metrics_json": write_metrics_json(result, d / "metrics.json")}
    (d / "metrics.md").write_text(markdown_table(result, title))
    paths["metrics_md"] = d / "metrics.md"
    motions = {}
    if real is not None:
        motions["real"] = real
    names = list(timeline_methods) if timeline_methods is not None else list(generated)[:2]
    motions.update({k: generated[k] for k in names})
    if motions:
        paths["beat_timeline"] = plot_beat_timeline(motions, audio, sr, fps, d / "beat_timeline.png")
    if real is not None and generated:
        paths["joint_speed"] = plot_speed_distributions(real, generated, fps, d / "joint_speed.png")
    return {k: str(v) for k, v in paths.items()}
