"""``facecapges ablate``: the ablation study of thesis 5.7 (Table 5.3), trained and measured.

**Variants** — all trained on the same data with the same budget (the base config's
``model:``/``train:`` sections: epochs, batch, optimizer, learning rates, loss weights,
discriminator schedule, seed):

* ``full`` — FaceCapGes as is (closed-loop trainer :mod:`facecapges.training.train`).
* ``no_head`` — "without head pose": ``ModelConfig(head_dim=0)``, no head encoder, the
  head rotation never reaches the network; same trainer and recipe.
* ``offline`` — "offline decoding": :class:`facecapges.network.bidirectional.BidirectionalDecoder`
  (same encoders, bidirectional torso/limb LSTMs over a whole segment, no closed-loop
  rollout), trained by :mod:`facecapges.training.bidirectional` on the same L = 34
  segments with the first N = 16 real poses as seed and losses on the 18 frames after.
* ``camn`` — the CaMN baseline (thesis 5.2.1, Table 5.2/5.3's CaMN row):
  :class:`facecapges.evaluation.camn.CaMN`, BEAT's cascaded bidirectional body/hands
  LSTMs with non-causal conv encoders on the same audio, face and head inputs, trained
  by the same trainer, recipe and segments as ``offline`` and evaluated like it.
  DiffSHEG is not reproduced (it needs HuBERT features; see that module).

**Given checkpoints** (``given``, ``--given full=STYLE_OR_FILE,camn=FILE``): a variant's
row comes from that checkpoint as it is (e.g. the shipped style as ``full``, or a CaMN
run stopped before its last epoch); when its stored recipe is not this one, the
variants table says so ("given checkpoint (not this recipe: …)").

**Reusing the shipped model for ``full``.** When the installed default style
(``beat2-scott-demo``) was trained by exactly this recipe — its stored model config
and training config (incl. epochs, hold-out frame and seed) equal the resolved ones,
same speaker, same clip names and split — it *is* the ``full`` variant and is not
trained again (``reuse_default``; the table says "(shipped checkpoint)"). The check
compares the checkpoint's metadata, not the cache's bytes: a cache prepared from
other BEAT files under the same clip names would pass it; turn reuse off then.
Likewise a variant whose run folder ``OUT/runs/<variant>/`` already holds a finished
model of the same recipe is loaded instead of retrained (a rerun after an
interrupted evaluation costs no training); ``retrain`` trains everything anew.

**Data and frames.** With a hold-out frame F (the base config's ``holdout_from`` or
the option): the variants train on frames < F of the clips of ``split`` (default
all) and are evaluated on frames ≥ F of every clip of the speaker; frames < F are the
real pool of the reference rows. Without one they train on the train clips and are
evaluated on the test clips (pool: the train clips).

**Evaluation** — the eval suite (:mod:`facecapges.evaluation.suite`) over the
held-out frames, both regions, rows ground truth / mean pose / random real segment
and the three variants; ``samples`` runs per variant and clip:

* the two closed-loop variants run frame by frame through the streaming generator
  (the live path), sample 0 from their cold-start neutral window, sample k > 0 from a
  random real N-frame window of the pool as history — exactly as ``facecapges eval``, through the
  same loop (:func:`facecapges.engine.generate.generate_poses`);
* the offline variant decodes the whole held-out sequence of a clip in one pass
  (:meth:`BidirectionalDecoder.generate`), seeded by **the same N-frame history** the
  streaming variants start from (sample 0: its own neutral window, chosen from the
  training frames as the closed-loop trainer chooses it; sample k: the same random
  real window), placed as the N frames before the sequence with "no input"
  embeddings. So every variant gets exactly the same information at inference — in
  particular the offline model is *not* given the first held-out real poses, which
  would hand it frames of the answer the streaming variants never see.

The random windows are drawn once per clip and shared by all variants.

**FGD** uses ``fgd_location`` when given; otherwise the shipped default style's
autoencoder when ``full`` reuses the shipped checkpoint (it was trained on the same
frames < F), otherwise one trained here on the pool frames into ``OUT/fgd``
(``fgd_epochs``, default 400 as the thesis).

**Files** in ``OUT``: ``ablation.json`` (the suite result, each variant's training
summary, the recipe, the command), ``ablation.md`` (Table 5.3 layout, both regions,
plus the BeatAlign control and training notes), ``runs/<variant>/`` (run folders).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.errors import UserError
from facecapges.evaluation.options import AblateOptions, parse_given, parse_offsets

VARIANTS: tuple[str, ...] = ("full", "no_head", "offline", "camn")
LABELS = {
    "full": "FaceCapGes (full)",
    "no_head": "without head pose",
    "offline": "offline decoding",
    "camn": "CaMN (baseline)",
}
#: Variants decoded offline (one pass per sequence): their loader and trainer builder.
SEGMENT_DECODERS = {
    "offline": (
        "facecapges.network.bidirectional:load_bidirectional",
        "facecapges.training.bidirectional:build_bidirectional_trainer",
    ),
    "camn": ("facecapges.evaluation.camn:load_camn", "facecapges.evaluation.camn:build_camn_trainer"),
}


def _resolve(ref: str):
    import importlib

    mod, name = ref.split(":")
    return getattr(importlib.import_module(mod), name)


def default_config_path() -> Path:
    """``configs/demo-beat2-scott.yaml`` of the source tree (the shipped model's recipe)."""
    return Path(__file__).resolve().parents[3] / "configs" / "demo-beat2-scott.yaml"


@dataclass
class Recipe:
    """What every variant is trained with (override dicts as ``build_trainer`` takes them)."""

    model_over: dict
    train_over: dict
    speaker: int
    split: str
    holdout_from: int | None
    config_path: str | None

    def resolved(self, model_extra: dict | None = None) -> tuple[dict, dict]:
        """Full model/train config dicts (defaults filled in) for one variant."""
        from facecapges.network.config import model_config_from_dict, to_dict, train_config_from_dict

        m = dict(self.model_over, **(model_extra or {}))
        return to_dict(model_config_from_dict(m)), to_dict(train_config_from_dict(self.train_over))


def make_recipe(
    config: Path | None, speaker: int, split: str | None, epochs: int | None, holdout_from: int | None, fps: float
) -> Recipe:
    from facecapges.network.config import load_config_file

    path = config if config is not None else default_config_path()
    if config is None and not path.is_file():
        raise UserError(f"{path}: the default base config is missing (run from a source checkout or pass --config)")
    model_over, train_over = load_config_file(path)
    # every variant starts from random weights: a fine-tuning base (train.init_from) has one
    # model's settings, and the variants differ in theirs — they are compared on equal terms
    train_over.pop("init_from", None)
    if epochs is not None:
        if epochs < 1:
            raise UserError("--epochs must be at least 1")
        train_over["epochs"] = epochs
    if holdout_from is not None:
        if holdout_from < 1:
            raise UserError("--holdout-from must be at least 1")
        train_over["holdout_from"] = holdout_from
        train_over.pop("holdout_fraction", None)  # one frame for every clip replaces the config's fraction
    if abs(fps - model_over.get("fps", timing.MODEL_FPS)) > 1e-6:
        model_over["fps"] = int(round(fps))
    if model_over.get("head_dim", 12) == 0:
        raise UserError(
            f"{path}: the base config already has head_dim 0; the 'without head pose' variant needs "
            "a base model with head input"
        )
    hf = train_over.get("holdout_from")
    chosen = split or ("all" if hf is not None else "train")
    if chosen not in ("train", "val", "test", "all"):
        raise UserError(f"--split must be train, val, test or all, got {chosen!r}")
    return Recipe(model_over, train_over, speaker, chosen, hf, str(path))


def _same_recipe(meta: dict, recipe: Recipe, model_extra: dict | None, clip_names: list[str]) -> str | None:
    """None when a checkpoint's metadata says it was trained by this recipe, else the reason."""
    mcfg, tcfg = recipe.resolved(model_extra)
    from facecapges.network.config import TrainConfig, to_dict

    # a field added to TrainConfig after the checkpoint was written counts at its default
    stored_t = dict(to_dict(TrainConfig()), **(meta.get("train_config") or {}))
    checks = [
        (meta.get("model_config") == mcfg, "model config differs"),
        (stored_t == tcfg, "training config differs"),
        (meta.get("epochs_trained") == tcfg["epochs"], "not trained for the full number of epochs"),
        (meta.get("speaker") == recipe.speaker, "other speaker"),
        (list(meta.get("clips") or []) == clip_names, "other clips"),
        (meta.get("split", recipe.split) == recipe.split, "other split"),
    ]
    for ok, why in checks:
        if not ok:
            return why
    return None


@dataclass
class TrainedVariant:
    name: str
    path: Path
    source: str  # "trained", "shipped checkpoint", "existing run", "given checkpoint …"
    seconds: float
    final_losses: dict = field(default_factory=dict)
    epochs: int | None = None  # epochs the checkpoint was trained for (None: the recipe's)


def _load_clip_arrays(cache: Path, speaker: int, split: str):
    from facecapges.training.segments import load_clips

    return load_clips(cache, speaker, split)


def _given_variant(v: str, ref: Path, recipe: Recipe, extra, names: list[str], say) -> TrainedVariant:
    """A variant's checkpoint given by the user, taken as it is (the table says when another recipe trained it)."""
    from facecapges.styles import load_style_or_file

    if v in SEGMENT_DECODERS:
        path, meta = ref, _resolve(SEGMENT_DECODERS[v][0])(ref)[1]
    else:
        ck = load_style_or_file(ref)
        path, meta = ck.path, ck.meta
    why = _same_recipe(meta, recipe, extra, names)
    source = "given checkpoint" + ("" if why is None else f" (not this recipe: {why})")
    say(f"[{v}] {path} taken as given" + ("" if why is None else f"; note: {why}"))
    return TrainedVariant(v, path, source, 0.0, meta.get("final_losses", {}), meta.get("epochs_trained"))


def _shipped_variant(v: str, recipe: Recipe, names: list[str], say) -> TrainedVariant | None:
    """The shipped network style when this recipe trained it, else None (and the reason said)."""
    from facecapges.styles import DEFAULT_NETWORK_STYLE, load_style

    ck = load_style(style=DEFAULT_NETWORK_STYLE)
    why = _same_recipe(ck.meta, recipe, None, names)
    if why is None:
        say(f"[{v}] the shipped checkpoint {ck.path.name} was trained by this recipe: reused")
        return TrainedVariant(
            v,
            ck.path,
            "shipped checkpoint",
            0.0,
            ck.meta.get("final_losses", {}),
            ck.meta.get("epochs_trained"),
        )
    say(f"[{v}] shipped checkpoint not reused ({why}); training")
    return None


def _existing_run(v: str, run: Path, recipe: Recipe, extra, names: list[str], say) -> TrainedVariant | None:
    """The model an earlier run of this recipe left in ``run``, else None."""
    import json

    from facecapges.styles import load_style

    done = run / "model.safetensors"
    if not done.is_file():
        return None
    try:
        meta = _resolve(SEGMENT_DECODERS[v][0])(done)[1] if v in SEGMENT_DECODERS else load_style(done).meta
    except UserError:
        meta = {}
    if not meta or _same_recipe(meta, recipe, extra, names) is not None:
        return None
    say(f"[{v}] {done} already holds this recipe's model: reused")
    info = run / "ablation_variant.json"
    secs = json.loads(info.read_text()).get("train_seconds", 0.0) if info.is_file() else 0.0
    return TrainedVariant(v, done, "existing run", float(secs), meta.get("final_losses", {}))


def _train_variant(v: str, run: Path, recipe: Recipe, extra, clips, meta_base: dict, progress: bool, say):
    """Train variant ``v`` into ``run`` by ``recipe``."""
    import json

    _, tcfg = recipe.resolved(extra)
    say(
        f"[{v}] training {LABELS[v]}: {tcfg['epochs']} epochs, batch {tcfg['batch_size']}, "
        f"{tcfg['optimizer']}, hold-out from {tcfg['holdout_from']}"
    )
    t0 = time.perf_counter()
    meta = dict(meta_base, variant=LABELS[v])
    if v in SEGMENT_DECODERS:
        build = _resolve(SEGMENT_DECODERS[v][1])
        tr = build(clips, run, dict(recipe.model_over), dict(recipe.train_over), meta)
        tr.fit(progress=progress)
    else:
        from facecapges.training.train import build_trainer

        tr = build_trainer(
            clips, run, dict(recipe.model_over, **(extra or {})), dict(recipe.train_over), meta, resume=False
        )
        tr.fit()
    seconds = time.perf_counter() - t0
    last = tr.history[-1] if tr.history else {}
    (run / "ablation_variant.json").write_text(json.dumps({"variant": v, "train_seconds": seconds}))
    return TrainedVariant(
        v, run / "model.safetensors", "trained", seconds, {k: val for k, val in last.items() if k != "epoch"}
    )


def train_variants(
    cache: Path,
    out: Path,
    recipe: Recipe,
    variants: Sequence[str] = VARIANTS,
    reuse_default: bool = True,
    retrain: bool = False,
    progress: bool = True,
    say=print,
    given: Mapping[str, str] | None = None,
) -> dict[str, TrainedVariant]:
    """Train (or reuse) every variant; see the module docstring.

    ``given`` maps variants to checkpoints (a file, or for closed-loop variants an
    installed style name) taken as they are, whatever recipe trained them; the table
    says so. Each variant: given, else the shipped style (``full``), else an existing run, else trained.
    """
    from facecapges.styles import DEFAULT_NETWORK_STYLE, list_styles

    cache_obj, clips = _load_clip_arrays(cache, recipe.speaker, recipe.split)
    names = [c.name for c in clips]
    meta_base = {
        "speaker": recipe.speaker,
        "clips": names,
        "split": recipe.split,
        "skeleton": cache_obj.index["skeleton"],
        "cache": str(cache),
    }
    result: dict[str, TrainedVariant] = {}
    for v in variants:
        run = out / "runs" / v
        extra = {"head_dim": 0} if v == "no_head" else None
        if given and v in given:
            result[v] = _given_variant(v, Path(given[v]), recipe, extra, names, say)
            continue
        if v == "full" and reuse_default and not retrain and DEFAULT_NETWORK_STYLE in list_styles():
            shipped = _shipped_variant(v, recipe, names, say)
            if shipped is not None:
                result[v] = shipped
                continue
        reused = None if retrain else _existing_run(v, run, recipe, extra, names, say)
        if reused is not None:
            result[v] = reused
            continue
        result[v] = _train_variant(v, run, recipe, extra, clips, meta_base, progress, say)
    return result


class _Runner:
    """Generates one variant's motion for a clip's held-out inputs from a given history."""

    def __init__(self, variant: TrainedVariant):
        self.variant = variant
        if variant.name in SEGMENT_DECODERS:
            self.model, self.meta = _resolve(SEGMENT_DECODERS[variant.name][0])(variant.path)
            self.ckpt = None
        else:
            from facecapges.styles import load_style, network_only

            self.ckpt = network_only(load_style(variant.path), "ablate")
            self.model, self.meta = self.ckpt.model, self.ckpt.meta
        self.cfg = self.model.cfg
        self.neutral = np.asarray(self.meta["neutral_window"], np.float32)
        self.ms: list[float] = []

    def run(self, inputs, history: np.ndarray | None, progress: bool) -> np.ndarray:
        """Poses for ``inputs`` from ``history`` (None: the variant's cold-start window); times the call."""
        t0 = time.perf_counter()
        if self.ckpt is None:
            out = self._decode(inputs, history)
        else:
            from facecapges.engine.generate import generate_poses

            out = generate_poses(self.ckpt, inputs, progress, history)[0]
        self.ms.append((time.perf_counter() - t0) * 1000 / max(inputs.n_frames, 1))
        return out

    def _decode(self, inputs, history: np.ndarray | None) -> np.ndarray:
        """A segment decoder's one pass over the whole sequence, seeded by ``history``."""
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            out = self.model.generate(
                inputs.audio, inputs.face, inputs.head, self.neutral if history is None else history
            )
        finally:
            torch.set_num_threads(threads)
        if not np.isfinite(out).all():
            raise UserError(f"variant {self.variant.name}: the model produced non-finite poses")
        return out


def _variant_clips(c, cache: Path, recipe: Recipe):
    """The clips the variants are evaluated on (the speaker's, from the hold-out frame on; else the test
    clips whole) and the real pool of the reference rows: (loaded clips, evaluated names, first frame, pool)."""
    F_ = recipe.holdout_from
    if F_ is not None:
        entries, start = c.clips(speaker=recipe.speaker), F_
    else:
        entries, start = c.clips(speaker=recipe.speaker, split="test"), 0
    loaded = {e["name"]: c.load(e["name"]) for e in entries}
    evaluated = [n for n in loaded if len(loaded[n]["pose"]) - start >= 32]
    if not evaluated:
        raise UserError(
            f"{cache}: no clip of speaker {recipe.speaker} has 32 frames to evaluate from frame {start} "
            "on (without a hold-out frame the test clips are evaluated)"
        )
    if F_ is not None:
        pool = [loaded[n]["pose"][:F_] for n in loaded]
    else:
        pool = [c.load(e["name"])["pose"] for e in c.clips(speaker=recipe.speaker, split="train")]
        if not pool:
            raise UserError(
                f"{cache}: no train clips of speaker {recipe.speaker} for the reference rows; "
                "use a hold-out frame (--holdout-from)"
            )
    return loaded, evaluated, start, pool


def evaluate_variants(
    cache: Path,
    recipe: Recipe,
    trained: dict[str, TrainedVariant],
    fgd=None,
    samples: int = 3,
    seed: int = 0,
    offsets_s: Sequence[float] = tuple(range(2, 61, 2)),
    progress: bool = True,
) -> dict:
    """The suite over the held-out frames for the reference rows and every variant (both regions)."""
    from facecapges.data.cache import Cache
    from facecapges.evaluation import baselines as bl
    from facecapges.evaluation.run import heldout_inputs
    from facecapges.evaluation.suite import Method, PairedClips

    if samples < 1:
        raise UserError("--samples must be at least 1")
    c = Cache(cache)
    fps, sr, F_ = c.fps, c.sr, recipe.holdout_from
    loaded, evaluated, start, pool = _variant_clips(c, cache, recipe)
    runners = {v: _Runner(t) for v, t in trained.items()}
    n_hist = next(iter(runners.values())).cfg.n_history
    weighted = all(loaded[n]["semantic_present"] for n in evaluated)
    rng = np.random.default_rng(seed)
    scored = PairedClips(sr, fps, offsets_s, progress)
    for name in evaluated:
        a = loaded[name]
        real, audio, _ = heldout_inputs(a, start, fps, sr)
        inputs_by_ref: dict = {}  # each model gets the head in its own training frame

        def inputs_for(r):
            ref = r.meta.get("head_reference_rot6d")
            key = None if ref is None else tuple(np.asarray(ref, np.float64).ravel().round(9))
            if key not in inputs_by_ref:
                inputs_by_ref[key] = heldout_inputs(a, start, fps, sr, ref)[2]
            return inputs_by_ref[key]

        histories = [None] + [bl.random_segment(pool, n_hist, rng) for _ in range(samples - 1)]
        if F_ is not None:
            segment = bl.random_segment([a["pose"]], len(real), rng, exclude=(0, start, len(a["pose"])))
        else:
            segment = bl.random_segment(pool, len(real), rng)
        methods: dict[str, Method] = {
            "ground truth": bl.ground_truth(real),
            "mean pose": bl.mean_pose_sequence(pool, len(real)),
            "random real segment": segment,
        }
        for v, r in runners.items():
            methods[LABELS[v]] = [r.run(inputs_for(r), h, progress) for h in histories]
        scored.add(real, methods, audio, a["semantic"][start:] if weighted else None, c.skeleton(name))
    result = scored.combine(fgd)
    result.update(
        clips=evaluated,
        first_frame=start,
        speaker=recipe.speaker,
        ms_per_frame={LABELS[v]: float(np.mean(r.ms)) for v, r in runners.items()},
    )
    return result


def _fgd_for(
    out: Path,
    recipe: Recipe,
    trained: dict[str, TrainedVariant],
    cache: Path,
    fgd_location: Path | None,
    fgd_epochs: int,
    progress: bool,
    say=print,
):
    from facecapges.evaluation.fgd import FGDConfig, fgd_paths, load_fgd, save_fgd, train_fgd
    from facecapges.evaluation.run import load_real_clips

    if fgd_location is not None:
        return load_fgd(fgd_location), str(fgd_paths(fgd_location)[0])
    full = trained.get("full")
    if (
        full is not None
        and full.source.startswith(("shipped checkpoint", "given checkpoint"))
        and fgd_paths(full.path)[1].is_file()
    ):
        say(f"FGD: the shipped checkpoint's autoencoder {fgd_paths(full.path)[0].parent}")
        return load_fgd(full.path), str(fgd_paths(full.path)[0])
    loc = out / "fgd"
    if fgd_paths(loc)[1].is_file():
        say(f"FGD: reusing {loc}")
        return load_fgd(loc), str(fgd_paths(loc)[0])
    if recipe.holdout_from is not None:
        clips, src = load_real_clips(cache=cache, speaker=recipe.speaker, split="all", before_frame=recipe.holdout_from)
    else:
        clips, src = load_real_clips(cache=cache, speaker=recipe.speaker, split="train")
    say(f"FGD: training an autoencoder ({fgd_epochs} epochs) on {src}")
    try:
        ev = train_fgd(clips, FGDConfig(epochs=fgd_epochs), progress=progress)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    save_fgd(ev, loc)
    return ev, str(fgd_paths(loc)[0])


def ablation_markdown(full: dict) -> str:
    """Table 5.3 layout (both regions) + BeatAlign control + the training notes."""
    from facecapges.evaluation.report import markdown_table

    res = full["result"]
    md = markdown_table(
        res,
        f"Ablation (thesis Table 5.3) — speaker {res['speaker']}, "
        f"{len(res['clips'])} clip(s) from frame {res['first_frame']}",
    )
    lines = [
        "",
        "### Variants",
        "",
        "| Variant | Model | Epochs | Train loss (rec) | Held-out loss (rec) | Train time | Inference ms/frame |",
        "|---|---|---|---|---|---|---|",
    ]
    for v, info in full["variants"].items():
        fl = info.get("final_losses") or {}
        rec = fl.get("rec")
        held = fl.get("held_rec")
        ms = res["ms_per_frame"].get(LABELS[v])
        took = f"{info['seconds'] / 60:.1f} min" if info["seconds"] else "—"
        where = Path(info["path"]).name if info["source"].startswith(("shipped", "given")) else f"runs/{v}/"
        lines.append(
            f"| {LABELS[v]} | {info['source']} ({where}) | {info['epochs']} | "
            f"{'—' if rec is None else f'{rec:.5f}'} | {'—' if held is None else f'{held:.5f}'} | "
            f"{took} | "
            f"{'—' if ms is None else f'{ms:.2f}'} |"
        )
    r = full["recipe"]
    lines += [
        "",
        f"Recipe: base config `{r['config_path']}`, training split `{r['split']}`, hold-out from frame "
        f"{r['holdout_from']}; every variant: {r['train']['epochs']} epochs, batch {r['train']['batch_size']}, "
        f"{r['train']['optimizer']}, lr_base {r['train']['lr_base']}, seed {r['train']['seed']}.",
        f"Samples per variant and clip: {full['samples']} (sample 0 from the model's cold-start neutral "
        "window, the others from the same random real histories for every variant). The offline variant "
        "decodes each held-out sequence in one pass seeded by that same history; the two closed-loop "
        "variants run frame by frame through the streaming generator.",
        f"FGD autoencoder: `{full['fgd_autoencoder']}`.",
    ]
    if "camn" in full["variants"]:
        lines += [
            "",
            "CaMN (baseline) is our implementation of BEAT's CaMN (`facecapges.evaluation.camn`: "
            "non-causal conv encoders, fusion cascade, 4-layer bidirectional body and hands LSTMs of 256 "
            "units) on the same audio, face and head inputs, trained by the same trainer, recipe and "
            "segments as the offline-decoding variant and decoded like it. DiffSHEG (thesis 5.2.1) is not "
            "reproduced: it needs HuBERT speech features from a pretrained model that cannot be obtained "
            "on this machine.",
        ]
    lines.append("")
    return md + "\n".join(lines)


def _document(result: dict, samples: int, fgd_file, command: str | None, recipe: Recipe, trained) -> dict:
    """ablation.json: the scores, the recipe and each variant's checkpoint and training."""
    _, tcfg = recipe.resolved()
    doc = {
        "result": result,
        "samples": samples,
        "fgd_autoencoder": fgd_file,
        "command": command,
        "recipe": {
            "config_path": recipe.config_path,
            "split": recipe.split,
            "holdout_from": recipe.holdout_from,
            "speaker": recipe.speaker,
            "model_over": recipe.model_over,
            "train": tcfg,
        },
        "variants": {
            v: {
                "label": LABELS[v],
                "path": str(t.path),
                "source": t.source,
                "seconds": t.seconds,
                "epochs": tcfg["epochs"] if t.epochs is None else t.epochs,
                "final_losses": t.final_losses,
            }
            for v, t in trained.items()
        },
    }
    return doc


def run_ablation(o: AblateOptions, say=print, command: str | None = None) -> dict:
    """Train + evaluate the variants ``o`` names, write ``ablation.json`` and ``ablation.md``; returns the document.

    Every output is checked before any training (``o.force``: write over a table; ``o.retrain``
    replaces the runs' models, so they count as outputs). ``say`` gets the progress, the
    table and the files written."""
    from facecapges.data.cache import Cache
    from facecapges.errors import check_output_dir
    from facecapges.evaluation.report import write_metrics_json

    cache, out, speaker, progress = o.cache, Path(o.out), o.speaker, not o.quiet
    variants = tuple(v.strip() for v in o.variants.split(",") if v.strip())
    given, offsets_s = parse_given(o.given), parse_offsets(o.offsets)
    if o.fgd_epochs < 1:
        raise UserError("--fgd-epochs must be at least 1")
    check_output_dir(
        out,
        ["ablation.json", "ablation.md"] + ([f"runs/{v}/model.safetensors" for v in variants] if o.retrain else []),
        o.force,
    )
    bad = [v for v in variants if v not in VARIANTS]
    if bad or not variants:
        raise UserError(f"--variants must be a comma-separated subset of {', '.join(VARIANTS)}, got {bad or '[]'}")
    c = Cache(cache)
    if not c.clips(speaker=speaker):
        have = sorted({e["speaker"] for e in c.clips()})
        raise UserError(f"{cache}: no clips of speaker {speaker} (speakers in the cache: {have})")
    recipe = make_recipe(o.config, speaker, o.split, o.epochs, o.holdout_from, c.fps)
    out.mkdir(parents=True, exist_ok=True)
    unknown = sorted(set(given) - set(variants))
    if unknown:
        raise UserError(f"--given names variant(s) not in --variants: {', '.join(unknown)}")
    trained = train_variants(cache, out, recipe, variants, o.reuse_default, o.retrain, progress, say, given)
    fgd, fgd_file = _fgd_for(out, recipe, trained, cache, o.fgd, o.fgd_epochs, progress, say)
    say("evaluating the variants on the held-out frames")
    result = evaluate_variants(cache, recipe, trained, fgd, o.samples, o.seed, offsets_s, progress)
    doc = _document(result, o.samples, fgd_file, command, recipe, trained)
    write_metrics_json(doc, out / "ablation.json")
    (out / "ablation.md").write_text(ablation_markdown(doc))
    say((out / "ablation.md").read_text())
    say(f"wrote {out / 'ablation.md'} and {out / 'ablation.json'} ({len(doc['variants'])} variant(s))")
    return doc
