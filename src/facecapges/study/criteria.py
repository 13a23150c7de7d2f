"""The three judging criteria of the user study (thesis 5.3.1), in one place.

Before the study the participants were told what each criterion means, so that all of
them rank on the same scale (thesis 5.3.1, "实验流程与指导"). The Chinese text below is
the thesis's wording; the English text is our faithful translation of it. The study
page shows both, the analysis labels its tables and plots with the English names.

Ranks are 1 = best … K = worst on every criterion (the thesis asks participants to
"rank" the K versions, 排名; it does not say which end is best, so we fix 1 = best, the
usual reading of a ranking).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Criterion:
    key: str  # identifier in answer files and results.json
    name: str  # English name
    name_zh: str  # the thesis's name
    definition: str  # English translation of the thesis's definition
    definition_zh: str  # the thesis's definition (5.3.1, item 1-3)

    def to_json(self) -> dict:
        return asdict(self)


CRITERIA: tuple[Criterion, ...] = (
    Criterion(
        key="realism",
        name="Realism",
        name_zh="真实性",
        definition="Is the motion as a whole natural and fluent, without anything obviously out of place, "
        "such as an abnormal orientation or a sudden jitter?",
        definition_zh="整体动作是否自然流畅，是否存在明显的违和感，如朝向异常或突然抖动",
    ),
    Criterion(
        key="synchrony",
        name="Synchrony",
        name_zh="同步性",
        definition="Are the gestures coordinated and consistent with the intonation and the rhythm of the speech?",
        definition_zh="手势动作与语调、语音节奏是否协调一致",
    ),
    Criterion(
        key="diversity",
        name="Diversity",
        name_zh="多样性",
        definition="Are the gestures rich and varied, avoiding long stretches of stillness or the repetition of a "
        "single movement?",
        definition_zh="手势是否丰富多变，避免长时间静止或重复单一动作",
    ),
)

CRITERION_KEYS: tuple[str, ...] = tuple(c.key for c in CRITERIA)
