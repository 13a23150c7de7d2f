"""Every shipped style is clean under its licence: BEAT / BEAT2 data only (CC BY-NC 4.0, attribution in its
card), nothing derived from ZEGGS (CC BY-NC-ND 4.0: no adapted copies — no retargeted data, database or model
trained on it, nor one fine-tuned from such a model).

The checks read what each style file records about its own making (its safetensors metadata), not only its
card's text: a network style's training clips, their datasets and licence (``train`` writes ``data``) and the
base it was fine-tuned from (``train_config.init_from``); a matching style's takes, the source file of every
database segment and its speech predictor's takes. A style of a format this file does not know fails: whoever
ships a new kind says here how its data is checked.
"""

from __future__ import annotations

import json
import re
import struct
from importlib import resources
from pathlib import Path

import pytest

from facecapges.data.beat import parse_clip_name

ASSETS = Path(str(resources.files("facecapges") / "assets"))
STYLES = ASSETS / "styles"
CLEAN_LICENCE = "CC BY-NC 4.0"
CLEAN_DATASETS = {"BEAT", "BEAT2"}
# a card must say so (the metadata is what is checked; the card is what a user reads) …
CLEAN_STATEMENT = re.compile(r"Nothing (in the file )?derives from ZEGGS")
# … and must not name the withdrawn ZEGGS style or the option that starts a style from another's weights
SOURCE_PHRASES = re.compile(r"zeggs-speech|--init-from|trained on ZEGGS", re.I)


def _meta(path: Path) -> dict:
    """The ``facecapges`` metadata of a safetensors file, read from its header (no tensor is loaded)."""
    with path.open("rb") as f:
        (n,) = struct.unpack("<Q", f.read(8))
        header = json.loads(f.read(n))
    return json.loads(header["__metadata__"]["facecapges"])


def _beat_clip(name: str) -> bool:
    """A BEAT clip name (``2_scott_0_1_1``): the names BEAT and BEAT2 takes keep in every cache and style."""
    clip = parse_clip_name(Path(name).stem.removesuffix("~mirror"))
    return clip is not None and clip.speaker < 100  # the caches give other mocap (ZEGGS: 100) ids >= 100


def _shipped() -> list[Path]:
    return sorted(STYLES.glob("*.safetensors"))


def test_the_package_ships_styles_and_no_zeggs_file():
    assert _shipped(), f"no style in {STYLES}"
    named = [p.relative_to(ASSETS) for p in ASSETS.rglob("*") if "zeggs" in p.name.lower()]
    assert named == [], f"files named after ZEGGS in the package: {named}"


def network_problems(meta: dict) -> list[str]:
    problems = []
    base = (meta.get("train_config") or {}).get("init_from")
    if base:
        problems.append(f"fine-tuned from {base!r} (a base's data cannot be checked here; train from random weights)")
    problems += [f"trained on {c!r}, not a BEAT clip" for c in meta.get("clips") or [] if not _beat_clip(c)]
    data = meta.get("data")
    if not data:
        return [*problems, "no `data` record (train writes each clip's dataset and licence)"]
    problems += [f"clip {c['name']!r} is from {c['dataset']!r}" for c in data["clips"] if c["dataset"] not in CLEAN_DATASETS]
    if [c["name"] for c in data["clips"]] != list(meta.get("clips") or []):
        problems.append("`data` does not list the clips it was trained on")
    if data.get("licence") != CLEAN_LICENCE:
        problems.append(f"licence {data.get('licence')!r}")
    return problems


def matching_problems(meta: dict) -> list[str]:
    problems = []
    if meta.get("licence") != CLEAN_LICENCE or "BEAT" not in meta.get("attribution", ""):
        problems.append(f"licence {meta.get('licence')!r}, attribution {meta.get('attribution')!r}")
    problems += [f"take {t['name']!r} ({t['source']})" for t in meta["takes"] if not _beat_clip(t["source"])]
    segments = meta["database"]["segments"]
    problems += [f"database segment {s['name']!r} from {s['source']}" for s in segments if not _beat_clip(s["source"])]
    pred = meta.get("predictor")
    if pred is not None:
        problems += [f"speech predictor trained on {t!r}" for t in pred["takes"] if not _beat_clip(t)]
        if any("init" in k for k in (pred.get("settings") or {})):
            problems.append("speech predictor started from another model's weights")
    return problems


CHECKS = {"facecapges-checkpoint-1": network_problems, "facecapges-matching-1": matching_problems}


@pytest.mark.parametrize("path", _shipped(), ids=lambda p: p.stem)
def test_a_shipped_style_records_beat_data_only(path):
    meta = _meta(path)
    check = CHECKS.get(meta.get("format"))
    assert check is not None, f"{path.name}: format {meta.get('format')!r}: add how its data is checked to this test"
    assert check(meta) == [], path.name


@pytest.mark.parametrize("path", _shipped(), ids=lambda p: p.stem)
def test_a_shipped_style_card_names_its_data_and_licence(path):
    card = path.with_suffix(".md")
    assert card.is_file(), f"{path.name} ships without a model card"
    text = " ".join(card.read_text(encoding="utf-8").split())
    for must in (CLEAN_LICENCE, "BEAT", "Liu et al."):
        assert must in text, f"{card.name} does not say {must!r}"
    assert CLEAN_STATEMENT.search(text), f"{card.name} does not say that nothing derives from ZEGGS"
    assert SOURCE_PHRASES.findall(text) == [], f"{card.name} names another source"


def test_the_packaged_fgd_autoencoder_says_it_is_beat_only():
    text = " ".join((ASSETS / "fgd" / "beat-upper-body" / "README.md").read_text(encoding="utf-8").split())
    assert CLEAN_LICENCE in text and "BEAT speaker 2" in text and "no ZEGGS" in text


@pytest.mark.parametrize(
    "meta, why",
    [
        ({"format": "facecapges-checkpoint-1", "clips": ["2_scott_0_1_1"], "train_config": {"init_from": "zeggs-speech"},
          "data": {"clips": [{"name": "2_scott_0_1_1", "dataset": "BEAT"}], "licence": CLEAN_LICENCE}}, "fine-tuned"),
        ({"format": "facecapges-checkpoint-1", "clips": ["zeggs_067_Speech_2_x_1_0"], "train_config": {},
          "data": {"clips": [{"name": "zeggs_067_Speech_2_x_1_0", "dataset": "ZEGGS (Ubisoft La Forge ZeroEGGS)"}],
                   "licence": "CC BY-NC-ND 4.0"}}, "not a BEAT clip"),
        ({"format": "facecapges-checkpoint-1", "clips": ["2_scott_0_1_1"], "train_config": {}}, "no `data` record"),
        ({"format": "facecapges-matching-1", "licence": "CC BY-NC-ND 4.0", "attribution": "ZEGGS", "takes": [],
          "database": {"segments": []}}, "licence"),
        ({"format": "facecapges-matching-1", "licence": CLEAN_LICENCE, "attribution": "BEAT",
          "takes": [{"name": "067_Speech_2_x_1_0", "source": "067_Speech_2_x_1_0.bvh"}],
          "database": {"segments": [{"name": "x", "source": "../shared/data/zeggs/067_Speech_2_x_1_0.bvh"}]}},
         "database segment"),
    ],
)
def test_the_checks_catch_a_zeggs_derived_style(meta, why):
    """What the shipped styles are held to fails on the shapes a ZEGGS-derived style had (the metadata of the
    former ``zeggs-speech`` and of the ``beat2-scott-demo`` fine-tuned from it)."""
    problems = CHECKS[meta["format"]](meta)
    assert any(why in p for p in problems), problems
