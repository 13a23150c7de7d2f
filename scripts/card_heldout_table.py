"""The held-out and unseen-speech figures of styles as one Markdown table (for model cards).

    python scripts/card_heldout_table.py LABEL=REPORT.json [LABEL=REPORT.json …] [--skip-unseen NAME …]

Each REPORT.json is a ``scripts/style_report.py`` output (the metrics of ``facecapges eval``: synchrony
controls and the realism figures of :mod:`facecapges.evaluation.realism`). One row per style and
stretch: each paired take's held-out 20 %, all held-out frames together, and each unseen audio.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

TARGETS = "0.8–1.25 | 0.8–1.25 | ≥ +1 | ≤ 1 | – | – | – | 0.1–0.5 | 0.5 | real's | < chance | > 0"
HEAD = (
    "| style | speech | wrist spread × real | wrist jerk × real | BeatAlign gap (sd; real's) | transitions / min | "
    "longest copy (s) | database used | returns in 20 s / min | pause / speech spread | real-vs-generated (control) | "
    "FGD vs training (real's) | onset → wrist peak s (chance; real's) | speed rise after onsets z (real's) |"
)


def _f(x, fmt: str = "{:.2f}") -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)


def _row(label: str, where: str, gen: dict, real: dict | None, rz: dict, control: dict | None, ex: dict) -> str:
    g = rz.get("generated", {})
    xg, xr = ex.get("generated", {}), ex.get("real")
    ctl = f" ({_f(control.get('classifier'))})" if control else ""
    ba = _f(gen.get("BA_gap_sd"), "{:+.2f}") + (f" ({_f(real.get('BA_gap_sd'), '{:+.2f}')})" if real else "")
    cells = [
        _f(gen.get("spread_ratio")),
        _f(gen.get("jerk_ratio")),
        ba,
        _f(g.get("transitions_per_min"), "{:.1f}"),
        _f(g.get("longest_copy_s"), "{:.1f}"),
        _f(g.get("database_share_used")),
        _f(g.get("returns_per_min"), "{:.1f}"),
        _f(g.get("silence_ratio")),
        _f(g.get("classifier")) + ctl,
        _f(xg.get("FGD")) + (f" ({_f(xr.get('FGD'))})" if xr else ""),
        f"{_f(xg.get('onset_lag_s'))} ({_f(xg.get('onset_lag_chance_s'))}"
        + (f"; {_f(xr.get('onset_lag_s'))})" if xr else ")"),
        _f(xg.get("onset_rise_z"), "{:+.1f}") + (f" ({_f(xr.get('onset_rise_z'), '{:+.1f}')})" if xr else ""),
    ]
    return f"| {label} | {where} | " + " | ".join(cells) + " |"


def table(reports: list[tuple[str, dict]], skip_unseen: set[str]) -> list[str]:
    lines = [HEAD, "|---|---|" + "---|" * 12, "| target | | " + TARGETS + " |"]
    for label, r in reports:
        for take, e in r["paired"].items():
            rz = e.get("realism", {})
            lines.append(_row(label, f"{take}, held-out {e['frames']} frames", e["generated_still_head"],
                              e["real"], rz, rz.get("control"), e.get("extra", {})))
        c = r.get("paired_combined")
        if c:
            rz = c.get("realism", {})
            lines.append(_row(label, "all held-out frames", c["generated"], c.get("real"), rz, rz.get("control"),
                              c.get("extra", {})))
        for name, e in r["unseen"].items():
            if name in skip_unseen:
                continue
            rz = e.get("realism", {})
            lines.append(_row(label, f"{name} (unseen)", e, None, rz, rz.get("control"), e.get("extra", {})))
    return lines


def main(argv: list[str]) -> int:
    skip = set()
    if "--skip-unseen" in argv:
        i = argv.index("--skip-unseen")
        skip, argv = set(argv[i + 1 :]), argv[:i]
    reports = [(lab, json.loads(Path(p).read_text())) for lab, p in (a.split("=", 1) for a in argv)]
    print("\n".join(table(reports, skip)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
