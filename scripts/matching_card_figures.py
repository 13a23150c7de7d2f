"""Append the figures of scripts/matching_validate.py runs to a matching style's model card.

    python scripts/matching_card_figures.py CARD.md LABEL=RUN.json [LABEL=RUN.json …]

Each RUN.json is one matching_validate.py output; its pooled means become one table row.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

COLUMNS = [
    ("spread_ratio", "wrist spread × real (window)"),
    ("jerk_ratio", "wrist jerk × real (window)"),
    ("spread_ratio_speaker", "spread × speaker"),
    ("jerk_ratio_speaker", "jerk × speaker"),
    ("ba_gap_sd", "BeatAlign gap (sd)"),
    ("ba_gap_sd_real", "… of the real motion"),
    ("pops_per_min", "pops / min"),
    ("pops_per_min_real", "… of the real motion"),
    ("switch_pops_per_min", "pops at switches / min"),
    ("pause_over_speech_spread", "pause / speech spread"),
]


def main(argv: list[str]) -> int:
    card = Path(argv[0])
    lines = [
        "",
        "## Figures",
        "",
        "Means over the takes' windows (each run from 4 lead-ins) by `scripts/matching_validate.py`: validation = "
        "database and predictor from frames [0, 0.64 T), scored on [0.64 T, 0.8 T); held-out = from [0, 0.8 T), "
        "scored on [0.8 T, T). Pops: frames whose largest joint angular acceleration exceeds the 99.9th percentile "
        "of the real training motion's. Targets (issue 25): spread and jerk 0.8–1.25×, gap ≥ +1 sd, ≤ 1 pop a "
        "minute, pause/speech spread 0.1–0.5.",
        "",
        "| run | " + " | ".join(h for _, h in COLUMNS) + " |",
        "|---|" + "---|" * len(COLUMNS),
    ]
    for spec in argv[1:]:
        label, path = spec.split("=", 1)
        mean = json.loads(Path(path).read_text())["mean"]
        cells = [f"{mean[k]:.2f}" if isinstance(mean.get(k), float) else "–" for k, _ in COLUMNS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += [
        "",
        'Reading the figures: the real motion itself "pops" many times a minute by this definition (BEAT2\'s',
        "converted fingers, the windows' own accelerations: see the real-motion columns), so the engine's own",
        'transitions are the "pops at switches" column. The windows are 10–12 s per take: a BeatAlign gap moves',
        'by about ± 0.5 sd between runs of the same engine. "× speaker" compares with the speaker\'s motion in',
        "the database's frames (what replaying him should match), \"× real (window)\" with the scored window's.",
        "",
        "Engine settings: `engine_config` in the file's metadata (`facecapges.matching.engine.EngineConfig`).",
        "Rebuild: `scripts/build-default-matching-style.sh`.",
    ]
    card.write_text(card.read_text(encoding="utf-8").rstrip("\n") + "\n" + "\n".join(lines) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
