"""The study design: clip order from balanced Latin squares, screen positions of the systems.

Vocabulary: N clips, K systems (the versions of each clip's body motion), P
participants. A *trial* is one clip shown to one participant with the K versions side
by side; a participant's *plan* is the ordered list of his N trials.

Clip order (thesis 5.3.1: the presentation order is balanced across participants with
a balanced Latin square)
    :func:`williams_square` gives the rows of a Williams design over ``n`` treatments:
    every treatment appears once in every serial position of each square, and every
    ordered pair (a, b), a ≠ b, appears as neighbours "a then b" equally often, so
    first-order carry-over effects are balanced. For even n one n × n square does this
    (each pair exactly once); for odd n no single square can, and the design is the
    square plus its mirror image (every row reversed), 2n rows, each pair exactly
    twice. Participant p follows row ``row_order[p]`` over the clips, where the rows
    are dealt out in a seeded random order, one full set of rows per R consecutive
    participants (R = n or 2n), and the clips are assigned to the square's symbols by a
    seeded random permutation. Clip order is therefore exactly balanced when P is a
    multiple of R; :func:`balance_report` says how far from that a plan is.

Screen positions of the systems (thesis 5.3.1: positions assigned at random, never
labelled)
    The P × N trials, taken in order (participant by participant, in presentation
    order), are cut into blocks of K consecutive trials. Each block gets its own random
    K × K Latin square (the cyclic square with rows, columns and symbols permuted by the
    seeded generator): trial k of the block shows, from left to right, the systems of
    row k. So within every complete block each system stands in each position exactly
    once — positions are random for each participant and clip, yet balanced: exactly
    when P·N is a multiple of K, otherwise within one trial per cell.

Everything comes from ``numpy.random.default_rng(seed)``: the same clips, systems,
participant count and seed always give the same plan.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np


def williams_square(n: int) -> list[list[int]]:
    """Rows of the balanced Latin square (Williams design) over treatments 0..n-1.

    n rows for even n, 2n rows (the square and its mirror) for odd n; each row is one
    order of all n treatments. Row r of the first square is ``(base + r) mod n`` with
    ``base = 0, 1, n-1, 2, n-2, …``.
    """
    if n < 1:
        raise ValueError(f"a Latin square needs at least one treatment, got {n}")
    base = [0] + [(j + 1) // 2 if j % 2 == 1 else n - j // 2 for j in range(1, n)]
    rows = [[(b + r) % n for b in base] for r in range(n)]
    if n % 2 == 1 and n > 1:
        rows += [row[::-1] for row in rows]
    return rows


def n_sequences(n_clips: int) -> int:
    """R, the number of distinct clip orders of the design (the rows of :func:`williams_square`)."""
    return len(williams_square(n_clips))


def default_participants(n_clips: int) -> int:
    """The smallest participant count with exactly balanced clip order: one participant per row."""
    return n_sequences(n_clips)


@dataclass(frozen=True)
class Trial:
    """One clip shown to one participant: ``systems[j]`` plays at screen position j (0 = leftmost)."""

    clip: str
    systems: tuple[str, ...]


@dataclass
class ParticipantPlan:
    id: str
    sequence: int  # the row of the Williams design this participant's clip order follows
    trials: list[Trial]
    # the participant's invitation token (:func:`new_token`): the only
    # credential the server accepts; "" in a plan that has none yet
    token: str = ""


@dataclass
class StudyPlan:
    clips: list[str]
    systems: list[str]
    seed: int
    participants: list[ParticipantPlan] = field(default_factory=list)

    def participant(self, pid: str) -> ParticipantPlan | None:
        return next((p for p in self.participants if p.id == pid), None)

    def to_json(self) -> dict:
        return {
            "clips": list(self.clips),
            "systems": list(self.systems),
            "seed": self.seed,
            "participants": [
                {
                    "id": p.id,
                    "sequence": p.sequence,
                    "trials": [{"clip": t.clip, "systems": list(t.systems)} for t in p.trials],
                    **({"token": p.token} if p.token else {}),
                }
                for p in self.participants
            ],
        }

    @classmethod
    def from_json(cls, doc: dict) -> StudyPlan:
        parts = [
            ParticipantPlan(
                p["id"],
                int(p["sequence"]),
                [Trial(t["clip"], tuple(t["systems"])) for t in p["trials"]],
                str(p.get("token", "")),
            )
            for p in doc["participants"]
        ]
        return cls(list(doc["clips"]), list(doc["systems"]), int(doc["seed"]), parts)


def new_token() -> str:
    """An invitation token: 22 URL-safe characters, 128 random bits."""
    import secrets

    return secrets.token_urlsafe(16)


def token_digest(token: str) -> str:
    """What the answer files record of a token (its SHA-256, shortened): proof without the secret."""
    import hashlib

    return hashlib.sha256(token.encode("utf-8")).hexdigest()[:32]


def participant_ids(n: int) -> list[str]:
    """``P01``, ``P02``, … (zero-padded to at least two digits)."""
    width = max(2, len(str(n)))
    return [f"P{i + 1:0{width}d}" for i in range(n)]


def _random_latin_square(k: int, rng: np.random.Generator) -> np.ndarray:
    rows, cols, syms = rng.permutation(k), rng.permutation(k), rng.permutation(k)
    cyclic = (rows[:, None] + cols[None, :]) % k
    return syms[cyclic]


def make_plan(clips: list[str], systems: list[str], n_participants: int | None = None, seed: int = 0) -> StudyPlan:
    """The plan of every participant: clip order (Williams design) and the systems' screen positions."""
    if len(set(clips)) != len(clips) or not clips:
        raise ValueError(f"clip ids must be unique and non-empty, got {clips}")
    if len(set(systems)) != len(systems) or len(systems) < 2:
        raise ValueError(f"need at least two distinct systems, got {systems}")
    n, k = len(clips), len(systems)
    n_participants = default_participants(n) if n_participants is None else int(n_participants)
    if n_participants < 1:
        raise ValueError(f"need at least one participant, got {n_participants}")
    rng = np.random.default_rng(seed)
    square = williams_square(n)
    r = len(square)
    clip_of_symbol = rng.permutation(n)
    row_order: list[int] = []
    while len(row_order) < n_participants:
        row_order += [int(x) for x in rng.permutation(r)]
    row_order = row_order[:n_participants]

    n_cells = n_participants * n
    positions: list[tuple[str, ...]] = []
    for _ in range(0, n_cells, k):
        block = _random_latin_square(k, rng)
        positions += [tuple(systems[int(s)] for s in row) for row in block]
    positions = positions[:n_cells]

    plan = StudyPlan(list(clips), list(systems), int(seed))
    for p, pid in enumerate(participant_ids(n_participants)):
        order = [clips[int(clip_of_symbol[s])] for s in square[row_order[p]]]
        trials = [Trial(c, positions[p * n + i]) for i, c in enumerate(order)]
        plan.participants.append(ParticipantPlan(pid, row_order[p], trials))
    return plan


def balance_report(plan: StudyPlan) -> dict:
    """How balanced a plan is: spreads of the position, serial-position and carry-over counts.

    ``*_spread`` is max − min over the cells of each count table (0 = exactly balanced).
    """
    pos = Counter((s, j) for p in plan.participants for t in p.trials for j, s in enumerate(t.systems))
    serial = Counter((t.clip, i) for p in plan.participants for i, t in enumerate(p.trials))
    carry = Counter((a.clip, b.clip) for p in plan.participants for a, b in zip(p.trials, p.trials[1:]))
    k, n = len(plan.systems), len(plan.clips)
    pos_counts = [pos[(s, j)] for s in plan.systems for j in range(k)]
    serial_counts = [serial[(c, i)] for c in plan.clips for i in range(n)]
    carry_counts = [carry[(a, b)] for a in plan.clips for b in plan.clips if a != b]

    def spread(x: list[int]) -> int:
        return max(x) - min(x) if x else 0

    return {
        "participants": len(plan.participants),
        "clips": n,
        "systems": k,
        "sequences": n_sequences(n),
        "position_spread": spread(pos_counts),
        "serial_position_spread": spread(serial_counts),
        "carry_over_spread": spread(carry_counts),
    }
