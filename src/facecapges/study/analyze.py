"""Analysis of a study's rankings: mean ranks, confidence intervals, Friedman and post-hoc tests.

Input: every ``answer`` event of ``STUDY_DIR/responses/*.json`` (first answer per
participant and trial). Each answer ranks the K systems 1 (best) … K on each criterion.

* **Mean rank** per system and criterion over all answers, with a 95 % confidence
  interval from a *participant-level* bootstrap: participants are resampled with
  replacement (10 000 resamples, seeded), all answers of a drawn participant go in,
  and the interval is the 2.5/97.5 percentiles of the resampled mean ranks. Answers of
  one participant are not independent, so resampling participants (not single answers)
  keeps the interval honest; with a single participant the interval is that
  participant's point value and is reported as not available (``null``).
* **Friedman test** (``scipy.stats.friedmanchisquare``) per criterion, one block per
  answer (participant × clip), the K systems as treatments; needs K ≥ 3 and at least
  two answers. Kendall's W = χ² / (n (K − 1)) is reported as its effect size.
* **Post-hoc**: for every pair of systems, a two-sided Wilcoxon signed-rank test
  (``scipy.stats.wilcoxon``) on the paired ranks of the same answers, p-values
  Holm-corrected within each criterion (we chose Wilcoxon + Holm over Nemenyi: it
  needs no large-sample approximation of the rank-sum range and the correction is
  uniformly more powerful than Bonferroni). With K = 2 the pair is the whole test.
* **Plots** in the manner of thesis figures 5.2–5.3 (the thesis shows the subjective
  ranking per criterion for the three models; its figures' exact styling is not in
  the text): ``mean_rank.png`` — grouped bars, one group per criterion, one bar per
  system, mean rank with the 95 % interval, lower is better; ``rank_shares.png`` —
  per criterion the share of answers that put each system 1st, 2nd, … as stacked bars.
* Outputs in ``--out``: ``results.json``, ``results.md`` (Markdown tables), the PNGs.
"""

from __future__ import annotations

import hmac
import json
from pathlib import Path

import numpy as np

from facecapges.errors import file_error
from facecapges.study.build import Study
from facecapges.study.criteria import CRITERIA
from facecapges.study.design import token_digest
from facecapges.study.store import answers_of

N_BOOT = 10_000
ALPHA = 0.05


def collect_answers(study: Study, left_out: list[str] | None = None) -> list[dict]:
    """Every participant's answers given with his invitation token, in participant then trial order.

    An answer counts only when its ``auth`` is the digest of the token of the participant
    the file belongs to (facecapges.study.store); the others — a file of an unknown
    participant, answers from before invitations, a forged file — are appended to
    ``left_out`` as ``"P01 clip 3"`` and not analysed. UserError on a corrupt file.
    """
    out = []
    expected = {p.id: token_digest(p.token) for p in study.plan.participants if p.token}
    for f in sorted(study.responses_dir.glob("*.json")):
        try:
            doc = json.loads(f.read_text(encoding="utf-8"))
            answers = answers_of(doc)
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
            raise file_error(f, f"not a valid answer file ({exc.__class__.__name__}: {str(exc)[:100]})") from None
        pid = f.stem
        for a in answers:
            auth = a.get("auth")
            if pid not in expected or not isinstance(auth, str) or not hmac.compare_digest(auth, expected[pid]):
                if left_out is not None:
                    left_out.append(f"{pid} clip {int(a['trial']) + 1}")
                continue
            out.append({"participant": pid, "trial": a["trial"], "clip": a["clip"], "ranks": a["ranks"]})
    return out


def rank_matrix(answers: list[dict], systems: list[str], criterion: str) -> np.ndarray:
    """(n_answers, K) ranks of ``systems`` on ``criterion``."""
    rows = [[a["ranks"][criterion][s] for s in systems] for a in answers]
    return np.array(rows, dtype=np.float64).reshape(-1, len(systems))


def holm(pvalues: list[float]) -> list[float]:
    """Holm–Bonferroni adjusted p-values (same order as given)."""
    p = np.asarray(pvalues, dtype=np.float64)
    m = len(p)
    order = np.argsort(p)
    adj = np.empty(m)
    running = 0.0
    for i, idx in enumerate(order):
        running = max(running, (m - i) * p[idx])
        adj[idx] = min(1.0, running)
    return adj.tolist()


def bootstrap_ci(ranks: np.ndarray, groups: np.ndarray, n_boot: int = N_BOOT, seed: int = 0) -> np.ndarray | None:
    """(K, 2) percentile interval of the mean ranks, resampling whole groups (participants)."""
    ids = np.unique(groups)
    if len(ids) < 2:
        return None
    rng = np.random.default_rng(seed)
    sums = np.stack([ranks[groups == g].sum(axis=0) for g in ids])  # (P, K)
    counts = np.array([(groups == g).sum() for g in ids], dtype=np.float64)
    draw = rng.integers(0, len(ids), size=(n_boot, len(ids)))
    means = sums[draw].sum(axis=1) / counts[draw].sum(axis=1)[:, None]  # (n_boot, K)
    return np.percentile(means, [100 * ALPHA / 2, 100 * (1 - ALPHA / 2)], axis=0).T


def analyze_criterion(answers: list[dict], systems: list[str], criterion: str) -> dict:
    from scipy import stats

    R = rank_matrix(answers, systems, criterion)
    groups = np.array([a["participant"] for a in answers])
    n, k = R.shape
    mean = R.mean(axis=0) if n else np.full(k, np.nan)
    ci = bootstrap_ci(R, groups) if n else None
    counts = [[int((R[:, i] == r).sum()) for r in range(1, k + 1)] for i in range(k)]
    res: dict = {
        "n_answers": n,
        "systems": {
            s: {
                "mean_rank": float(mean[i]),
                "ci95": None if ci is None else [float(ci[i, 0]), float(ci[i, 1])],
                "rank_counts": counts[i],
            }
            for i, s in enumerate(systems)
        },
    }
    if k >= 3 and n >= 2:
        chi2, p = (float(x) for x in stats.friedmanchisquare(*R.T))
        res["friedman"] = {"chi2": chi2, "df": k - 1, "p": p, "kendall_w": chi2 / (n * (k - 1))}
    else:
        res["friedman"] = None
    pairs, raw = [], []
    for i in range(k):
        for j in range(i + 1, k):
            d = R[:, i] - R[:, j]
            if n == 0 or np.all(d == 0):
                stat, p = float("nan"), 1.0
            else:
                w = stats.wilcoxon(R[:, i], R[:, j], zero_method="wilcox", alternative="two-sided")
                stat, p = float(w.statistic), float(w.pvalue)
            pairs.append(
                {
                    "a": systems[i],
                    "b": systems[j],
                    "mean_diff": float(d.mean()) if n else float("nan"),
                    "a_better": int((d < 0).sum()),
                    "b_better": int((d > 0).sum()),
                    "wilcoxon_w": stat,
                    "p": p,
                }
            )
            raw.append(p)
    for pr, adj in zip(pairs, holm(raw) if raw else []):
        pr["p_holm"] = adj
        pr["significant"] = bool(adj < ALPHA)
    res["pairwise"] = pairs
    return res


def _fmt_p(p: float | None) -> str:
    if p is None or not np.isfinite(p):
        return "–"
    return f"{p:.2e}" if p < 1e-3 else f"{p:.3f}"


def markdown(results: dict) -> str:
    systems = results["systems"]
    lines = [
        f"# User study: {results['n_participants']} participants, {results['n_answers']} answers, "
        f"{results['n_clips']} clips, {len(systems)} systems",
        "",
        "Mean rank (1 = best) with the 95 % participant-bootstrap interval.",
        "",
        "| system | " + " | ".join(c.name for c in CRITERIA) + " |",
        "|---|" + "---|" * len(CRITERIA),
    ]
    for s in systems:
        cells = []
        for c in CRITERIA:
            r = results["criteria"][c.key]["systems"][s]
            ci = r["ci95"]
            cells.append(f"{r['mean_rank']:.2f}" + (f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else ""))
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Friedman test per criterion (blocks = answers):",
        "",
        "| criterion | χ² | df | p | Kendall's W |",
        "|---|---|---|---|---|",
    ]
    for c in CRITERIA:
        f = results["criteria"][c.key]["friedman"]
        if f is None:
            lines.append(f"| {c.name} | – | – | – | – |")
        else:
            lines.append(f"| {c.name} | {f['chi2']:.2f} | {f['df']} | {_fmt_p(f['p'])} | {f['kendall_w']:.3f} |")
    lines += [
        "",
        "Post-hoc pairs: Wilcoxon signed-rank on paired ranks, Holm-corrected per criterion "
        "(a<b: answers ranking a above b).",
        "",
        "| criterion | pair | a<b | b<a | mean rank a−b | p | p (Holm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in CRITERIA:
        for pr in results["criteria"][c.key]["pairwise"]:
            star = " *" if pr.get("significant") else ""
            lines.append(
                f"| {c.name} | {pr['a']} vs {pr['b']} | {pr['a_better']} | {pr['b_better']} | "
                f"{pr['mean_diff']:+.2f} | {_fmt_p(pr['p'])} | {_fmt_p(pr['p_holm'])}{star} |"
            )
    return "\n".join(lines) + "\n"


def plot(results: dict, out: Path) -> list[Path]:
    from facecapges.io.plots import cjk_font, pyplot

    plt = pyplot()  # with the CJK fallback font: the criteria's Chinese names drawn, not boxes

    systems = results["systems"]
    k = len(systems)
    crit = list(CRITERIA)
    colors = plt.get_cmap("tab10").colors  # a ListedColormap
    paths = []

    fig, ax = plt.subplots(figsize=(2.2 + 1.9 * len(crit), 3.8), dpi=120)
    width = 0.8 / k
    x = np.arange(len(crit))
    for i, s in enumerate(systems):
        m = [results["criteria"][c.key]["systems"][s]["mean_rank"] for c in crit]
        ci = [results["criteria"][c.key]["systems"][s]["ci95"] for c in crit]
        err = np.array([[mi - c[0], c[1] - mi] if c else [0.0, 0.0] for mi, c in zip(m, ci)]).T
        pos = x - 0.4 + width * (i + 0.5)
        ax.bar(pos, m, width * 0.92, yerr=err, capsize=3, color=colors[i % 10], label=s)
        for px, v in zip(pos, m):
            ax.text(px, 0.05, f"{v:.2f}", ha="center", va="bottom", fontsize=7, color="white", rotation=90)
    ax.set_xticks(x, [f"{c.name}\n{c.name_zh}" if cjk_font() else c.name for c in crit])
    ax.set_ylim(0, k + 0.3)
    ax.set_ylabel("mean rank (1 = best)")
    ax.set_title(f"Subjective ranking ({results['n_participants']} participants, {results['n_answers']} answers)")
    ax.legend(fontsize=8, ncol=min(k, 4), loc="upper center", bbox_to_anchor=(0.5, -0.18), frameon=False)
    fig.tight_layout()
    paths.append(out / "mean_rank.png")
    fig.savefig(paths[-1])
    plt.close(fig)

    fig, axes = plt.subplots(1, len(crit), figsize=(2.0 + 2.6 * len(crit), 3.6), dpi=120, sharey=True)
    shades = plt.get_cmap("viridis")(np.linspace(0.15, 0.9, k))
    for ax, c in zip(np.atleast_1d(axes), crit):
        n = max(results["criteria"][c.key]["n_answers"], 1)
        bottom = np.zeros(k)
        for r in range(k):
            share = np.array([results["criteria"][c.key]["systems"][s]["rank_counts"][r] / n for s in systems])
            ax.bar(np.arange(k), share * 100, bottom=bottom, color=shades[r], label=f"rank {r + 1}")
            bottom += share * 100
        ax.set_xticks(np.arange(k), systems, rotation=30, ha="right", fontsize=8)
        ax.set_title(c.name)
    np.atleast_1d(axes)[0].set_ylabel("% of answers")
    np.atleast_1d(axes)[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    paths.append(out / "rank_shares.png")
    fig.savefig(paths[-1])
    plt.close(fig)
    return paths


def analyze_study(study: Study, out: str | Path, participants: list[str] | None = None) -> dict:
    """Write results.json, results.md, mean_rank.png and rank_shares.png into ``out``; return the results.

    ``participants``: analyse only these (e.g. the balanced-Latin-square session of a
    study that also ran free sessions, as thesis figure 5.3 does beside figure 5.2).
    """
    out = Path(out)
    answers = collect_answers(study)
    if participants is not None:
        answers = [a for a in answers if a["participant"] in set(participants)]
    systems = study.systems
    results = {
        "study": str(study.dir),
        "systems": systems,
        "n_clips": len(study.plan.clips),
        "n_participants": len({a["participant"] for a in answers}),
        "n_answers": len(answers),
        "participants": sorted({a["participant"] for a in answers}),
        "criteria": {
            c.key: {"name": c.name, "name_zh": c.name_zh, **analyze_criterion(answers, systems, c.key)}
            for c in CRITERIA
        },
        "methods": {
            "ci": f"participant bootstrap, {N_BOOT} resamples, percentile 95 %",
            "omnibus": "Friedman (scipy.stats.friedmanchisquare), blocks = answers",
            "post_hoc": "Wilcoxon signed-rank, two-sided, Holm-corrected per criterion",
        },
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    (out / "results.md").write_text(markdown(results), encoding="utf-8")
    results["plots"] = [str(p) for p in plot(results, out)]
    return results
