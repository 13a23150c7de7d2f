"""``facecapges eval`` end to end: checkpoint + cache → metrics, plots, video.

**Held-out frames.** With ``holdout_from = F`` every clip of the speaker (any split)
is evaluated on frames ``F…T−1`` and its frames ``0…F−1`` form the real pool (mean
pose, random real segment). Without it, the clips of ``split`` (default test) are
evaluated whole and the pool is the speaker's train clips (falling back to the
evaluated clips themselves, with a warning, when the cache has none).

**Generation.** The checkpoint runs frame by frame through
:func:`facecapges.engine.generate.generate_poses` — the one whole-recording loop, on the streaming path
of live use, whatever the engine —
from a cold start at the first evaluated frame, on the clip's own audio, face
weights and head rotation from the cache.

**Samples.** The model is run ``samples`` times per clip: sample 0 starts from the
checkpoint's own cold-start window, sample k > 0 from a random real window of
frames of the pool as its history (as many as the checkpoint's neutral window). SRGR, BA and L1DIV are averaged over
samples, FGD pools them, and eq. 5.11 (``L1DIV_samples``) is computed across them.
Plots and video show sample 0.

**Rows.** ground truth, mean pose, random real segment (same length, from the pool,
never overlapping the evaluated frames) and the model. Several clips are merged by
:func:`facecapges.evaluation.suite.combine_clips` (frame-weighted means; FGD pooled).
SRGR is semantic-weighted only when every evaluated clip has a semantic file.

**Unseen audio** (``--audio``, ``EvalOptions.audio``): the model runs with neutral face and resting head
(no face/head track exists for it); BeatAlign (+ control), L1DIV and FGD against all
of the speaker's real motion in the cache.

**Realism** (issue #25 §3, :mod:`facecapges.evaluation.realism`): the ``realism`` section of
``paired`` and of each unseen audio, on sample 0 of every method: transitions against the
speaker's training frames (the real pool), repetition against the engine's database (its
``database_poses()`` when it replays one, as motion matching does, else the training frames), the silence ratio, and
the real-vs-generated classifier against the held-out real windows with its control (held-out
real vs the training frames). ``metrics.md`` shows each figure beside its target.

**Timing** (:mod:`facecapges.evaluation.timing`): the ``timing`` section of ``paired`` (every method,
ground truth = the real held-out motion) and of each unseen audio: onset → next wrist-speed-peak lag and
the wrist-speed rise after onsets, each beside the same statistic at random times.

**FGD autoencoder** (:func:`facecapges.evaluation.fgd.find_fgd`): ``--fgd``, else the checkpoint's own
``NAME.fgd/``, else the one that ships with the package (BEAT speaker 2's upper body) — so every engine
gets an FGD; ``fgd_autoencoder`` / ``fgd_autoencoder_source`` in ``metrics.json`` say which.

**Engines.** Evaluation uses only the engine interface (:class:`facecapges.engine.contract.GestureEngine`:
its stream, ``fps``, ``meta``, ``skeleton``, ``neutral_window``, ``display_name``, ``database_poses()``):
the thesis network and a motion-matching checkpoint run the same path.

**Files** in ``out``: ``metrics.json`` (``paired`` and ``unseen_audio`` sections),
``metrics.md``, ``beat_timeline.png``, ``joint_speed.png`` and
``real_vs_generated.mp4`` (first evaluated clip, with its audio).
"""

from __future__ import annotations

import functools
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facecapges import timing
from facecapges.errors import UserError, check_output_dir, echo, echo_warning, file_error
from facecapges.evaluation.options import EvalOptions, parse_offsets

if TYPE_CHECKING:
    from facecapges.engine.contract import GestureEngine


def load_real_clips(
    cache: Path | None = None,
    speaker: int = 2,
    split: str = "train",
    bvh: Sequence[Path] | None = None,
    before_frame: int | None = None,
    fps: float = timing.MODEL_FPS,
    own_holdout: bool = False,
) -> tuple[list[np.ndarray], str]:
    """Real upper-body poses (T, 47, 6) from a cache or BVH files, cut at ``before_frame`` (or, with
    ``own_holdout``, each cached clip at its own ``holdout_from``: its first 80 %)."""
    clips: list[np.ndarray] = []
    if bvh and own_holdout:
        raise UserError("--holdout-tail needs a cache (BVH files carry no hold-out frame)")
    if bvh:
        from facecapges.io.bvh import read_bvh
        from facecapges.skeleton import motion_to_pose

        for p in bvh:
            b = read_bvh(p)
            missing = b.skeleton.missing()
            if missing:
                raise file_error(p, f"not a BEAT upper-body skeleton (missing joints: {', '.join(missing[:5])})")
            pose = motion_to_pose(b.skeleton, b.motion)[0]
            clips.append(timing.resample(pose, b.fps, fps) if abs(b.fps - fps) > 1e-6 else pose)
        source = ", ".join(str(p) for p in bvh)
    else:
        from facecapges.data.cache import Cache

        if cache is None:
            raise UserError("give a prepared cache or BVH files")
        c = Cache(cache)
        entries = c.select(speaker, split)
        clips = [c.load(e["name"])["pose"] for e in entries]
        source = f"{cache} (speaker {speaker}, split {split})"
        if own_holdout:
            if before_frame is not None:
                raise UserError("give --holdout-from or --holdout-tail, not both")
            from facecapges.data.prepare import holdout_frame

            clips = [x[: int(e.get("holdout_from") or holdout_frame(len(x)))] for x, e in zip(clips, entries)]
            source += ", each clip's frames before its hold-out (its first 80 %)"
    if before_frame is not None:
        if before_frame < 1:
            raise UserError("--holdout-from must be at least 1")
        clips = [x[:before_frame] for x in clips]
        source += f", frames < {before_frame}"
    return [np.asarray(x, np.float32) for x in clips if len(x)], source


def heldout_inputs(arrays: dict, start: int, fps: float, sr: int, head_reference=None):
    """A cached clip from frame ``start`` on: real poses (T, 47, 6), audio (S,), model inputs.

    The audio starts at the first sample frame ``start`` owns, so frame t of the
    inputs is frame ``start + t`` of the clip. ``head_reference`` (the checkpoint's
    ``head_reference_rot6d``) maps the cached skeleton-frame head into the model's
    camera frame (:func:`facecapges.capture.head_pose.skeleton_head_to_camera`).
    """
    from facecapges.engine.inputs import FrameInputs

    real = arrays["pose"][start:].astype(np.float32)
    s0 = int(timing.frame_sample_bounds(start, fps, sr)[0])
    audio = arrays["audio"][s0:].astype(np.float32)
    head = arrays["head"][start:]
    if head_reference is not None:
        from facecapges.capture.head_pose import skeleton_head_to_camera

        head = skeleton_head_to_camera(head, head_reference)
    inputs = FrameInputs(
        audio=timing.frame_audio(audio, len(real), fps, sr), face=arrays["face"][start:], head=head, fps=fps, notes=[]
    )
    return real, audio, inputs


def _real_window(pool: Sequence[np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """A random real window (n, 47, 6) from the pool: another cold-start history."""
    from facecapges.evaluation.baselines import random_segment

    return random_segment(pool, n, rng)


def history_frames(ckpt) -> int:
    """Frames of pose history a stream of ``ckpt`` starts from (its neutral window's length)."""
    return len(ckpt.neutral_window)


def engine_database(ckpt: GestureEngine, training: Sequence[np.ndarray]) -> tuple[list[np.ndarray] | None, str]:
    """The frames repetition is measured against: the engine's database if it replays one, else the
    training frames."""
    database = ckpt.database_poses()
    if database is not None:
        return [np.asarray(database, np.float32)], "the engine's database"
    if training:
        return [np.asarray(x, np.float32) for x in training], "the speaker's training frames in the cache"
    return None, "no database (no training frames): repetition not computed"


@dataclass
class _Selection:
    """The clips ``run_eval`` evaluates: the speaker, the first evaluated frame, every loaded clip of the
    speaker (name → cached arrays) and the names of those with enough frames to evaluate."""

    speaker: int
    start: int
    loaded: dict[str, dict]
    evaluated: list[str]


@dataclass
class _Paired:
    """The paired scores (``result``), each method's first sample per clip (``shown_clips``), the
    held-out real motion and audio, and the first clip's name, real motion, methods and audio."""

    result: dict
    shown_clips: dict[str, list[np.ndarray]]
    heldout_real: list[np.ndarray]
    heldout_audio: list[np.ndarray]
    first: tuple[str, np.ndarray, dict[str, np.ndarray], np.ndarray]


def _select_clips(o: EvalOptions, c, ckpt: GestureEngine, warnings: list[str]) -> _Selection:
    """Select clips: the speaker's clips of ``o.split`` (or every clip from ``o.holdout_from`` on) with
    at least 32 frames to evaluate; the shorter ones go to ``warnings``."""
    speaker, split, holdout_from = o.speaker, o.split, o.holdout_from
    if speaker is None:
        speaker = int(ckpt.meta.get("speaker", 2))
    if holdout_from is not None:
        if holdout_from < 1:
            raise UserError("--holdout-from must be at least 1")
        entries = c.clips(speaker=speaker)
        start = holdout_from
    else:
        entries = c.clips(speaker=speaker, split=None if split == "all" else split)
        start = 0
    if not entries:
        have = sorted({(e["speaker"], e["split"]) for e in c.clips()})
        raise UserError(
            f"{o.cache}: no {split!r} clips of speaker {speaker} to evaluate (speaker/split pairs: {have}); "
            "use --holdout-from FRAME to evaluate the end of every clip"
        )
    loaded = {e["name"]: c.load(e["name"]) for e in entries}
    min_frames = 32
    evaluated = [n for n in loaded if len(loaded[n]["pose"]) - start >= min_frames]
    for n in loaded:
        if n not in evaluated:
            warnings.append(f"clip {n}: fewer than {min_frames} frames from frame {start} on; not evaluated")
    if o.samples < 1:
        raise UserError("--samples must be at least 1")
    if not evaluated:
        raise UserError(
            f"{o.cache}: no clip of speaker {speaker} has {min_frames} frames to evaluate from frame {start} on"
        )
    return _Selection(speaker, start, loaded, evaluated)


def _real_pool(
    c, sel: _Selection, holdout_from: int | None, warnings: list[str]
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The real pool for the baselines and the speaker's training frames (empty when the cache has none
    outside the evaluated clips: the pool then falls back to the evaluated clips, with a warning)."""
    loaded = sel.loaded
    if holdout_from is not None:
        pool = [loaded[n]["pose"][:holdout_from] for n in loaded]
    else:
        pool = [
            c.load(e["name"])["pose"] for e in c.clips(speaker=sel.speaker, split="train") if e["name"] not in loaded
        ]
    training = list(pool)
    if holdout_from is None and not pool:
        warnings.append(
            f"no train clips of speaker {sel.speaker} outside the evaluated ones: mean pose and random "
            "segment come from the evaluated clips"
        )
        pool = [loaded[n]["pose"] for n in sel.evaluated]
    return pool, training


def _fgd_autoencoder(ckpt: GestureEngine, o: EvalOptions, say: Callable[[str], None], warnings: list[str]):
    """The FGD autoencoder (or None, with a warning), where it was found and how it was chosen."""
    from facecapges.evaluation.fgd import fgd_paths, find_fgd, load_fgd

    loc, fgd_source = find_fgd(ckpt.path, o.fgd)
    if loc is None:
        warnings.append(
            f"no FGD autoencoder ({fgd_source}): FGD not computed (train one with "
            f"`facecapges fgd-train --checkpoint {ckpt.path}`)"
        )
        return None, loc, fgd_source
    fgd = load_fgd(loc)
    say(f"FGD autoencoder: {fgd_paths(loc)[0]} ({fgd_source})")
    return fgd, loc, fgd_source


def _samples(ckpt: GestureEngine, inputs, samples: int, pool, rng, progress: bool) -> tuple[list[np.ndarray], float]:
    """``samples`` runs of ``ckpt`` on ``inputs``: the first from its own cold start, the others from a
    random real window of the pool; with the first run's ms per frame."""
    from facecapges.engine.generate import generate_poses

    gen, ms = generate_poses(ckpt, inputs, progress=progress)
    gens = [gen] + [
        generate_poses(ckpt, inputs, progress, _real_window(pool, history_frames(ckpt), rng))[0]
        for _ in range(samples - 1)
    ]
    return gens, ms


def _random_segment(a: dict, real: np.ndarray, name: str, start: int, pool, holdout: bool, rng) -> np.ndarray:
    """The random real segment baseline for one clip: from the pool (with hold-out, the clip's own
    frames before ``start``), never overlapping the evaluated frames."""
    from facecapges.evaluation import baselines as bl

    if holdout:
        seg_pool, excl = [a["pose"]], (0, start, len(a["pose"]))
    else:
        seg_pool, excl = pool, None
    try:
        return bl.random_segment(seg_pool, len(real), rng, exclude=excl)
    except ValueError:
        try:
            return bl.random_segment(pool + [a["pose"]], len(real), rng, exclude=(len(pool), start, len(a["pose"])))
        except ValueError:
            raise UserError(
                f"clip {name}: {len(real)} frames from frame {start} on, but no real stretch that long outside "
                "them for the random real segment; use a later --holdout-from"
            ) from None


def _score_paired(
    o: EvalOptions, c, ckpt: GestureEngine, sel: _Selection, pool, fgd, weighted: bool, rng
) -> tuple[_Paired, list[float]]:
    """Score paired: every evaluated clip's held-out frames, ground truth, mean pose, random real
    segment and the model's samples; with the model's ms per frame per clip."""
    from facecapges.evaluation import baselines as bl
    from facecapges.evaluation.suite import Method, PairedClips

    fps, sr, start, progress = c.fps, c.sr, sel.start, not o.quiet
    scored, ms_all = PairedClips(sr, fps, parse_offsets(o.offsets), progress), []
    shown_clips: dict[str, list[np.ndarray]] = {}  # each method's first sample per clip, for the realism section
    heldout_real: list[np.ndarray] = []
    heldout_audio: list[np.ndarray] = []
    first: tuple[str, np.ndarray, dict[str, np.ndarray], np.ndarray] | None = None  # its first sample per method
    for name in sel.evaluated:
        a = sel.loaded[name]
        real, audio, inputs = heldout_inputs(a, start, fps, sr, ckpt.meta.get("head_reference_rot6d"))
        gens, ms = _samples(ckpt, inputs, o.samples, pool, rng, progress)
        ms_all.append(ms)
        segment = _random_segment(a, real, name, start, pool, o.holdout_from is not None, rng)
        methods: dict[str, Method] = {
            "ground truth": bl.ground_truth(real),
            "mean pose": bl.mean_pose_sequence(pool, len(real)),
            "random real segment": segment,
            ckpt.display_name: gens,
        }
        scored.add(real, methods, audio, a["semantic"][start:] if weighted else None, c.skeleton(name))
        heldout_real.append(real)
        heldout_audio.append(audio)
        for k, v in methods.items():
            shown_clips.setdefault(k, []).append(v if isinstance(v, np.ndarray) else v[0])
        if first is None:
            first = (name, real, {k: v if isinstance(v, np.ndarray) else v[0] for k, v in methods.items()}, audio)
    assert first is not None  # at least one clip was evaluated
    return _Paired(scored.combine(fgd), shown_clips, heldout_real, heldout_audio, first), ms_all


def _realism(c, ckpt: GestureEngine, paired: _Paired, training: list[np.ndarray], skel, seed: int):
    """The realism section's function for this run (:func:`facecapges.evaluation.realism.realism_section`
    with the held-out real motion, the reference and the engine's database bound)."""
    from facecapges.evaluation.realism import realism_section

    database, db_source = engine_database(ckpt, training)
    return functools.partial(
        realism_section,
        sr=c.sr,
        fps=c.fps,
        skeleton=skel,
        real_heldout=paired.heldout_real,
        reference=training or paired.heldout_real,
        database=database,
        database_source=db_source,
        seed=seed,
        control_reference=training or None,  # no other real motion of the speaker: no control
        reference_source="the speaker's training motion"
        if training
        else "the evaluated real motion (no training frames)",
    )


def _score_unseen(
    o: EvalOptions, c, ckpt: GestureEngine, speaker: int, pool, fgd, skel, realism, rng, warnings: list[str]
) -> dict[str, dict]:
    """Score unseen audio: each ``o.audio`` file with neutral face and resting head, against all of the
    speaker's real motion in the cache."""
    from facecapges.evaluation.suite import evaluate_unpaired
    from facecapges.evaluation.timing import timing_section
    from facecapges.io.audio import load_audio

    fps, sr, progress, model_name = c.fps, c.sr, not o.quiet, ckpt.display_name
    unseen = {}
    all_real = [c.load(e["name"])["pose"] for e in c.clips(speaker=speaker)]  # every real clip
    for path in o.audio:
        inputs = ckpt.prepare_inputs(path)
        warnings += inputs.notes
        gens, _ = _samples(ckpt, inputs, o.samples, pool, rng, progress)
        wav = load_audio(path, sr)
        res = evaluate_unpaired(
            {model_name: gens},
            wav,
            sr,
            fps,
            fgd=fgd,
            fgd_reference=all_real,
            offsets_s=parse_offsets(o.offsets),
            progress=progress,
            skeleton=skel,
        )
        res["realism"] = realism({model_name: [gens[0]]}, [wav])
        res["timing"] = timing_section({model_name: [gens[0]]}, [wav], sr, fps, skel, o.seed)
        unseen[str(path)] = res
    return unseen


def _write_outputs(
    o: EvalOptions, c, model_name: str, sel: _Selection, paired: _Paired, unseen: dict, fgd_line: str, warnings
) -> dict[str, str]:
    """Write outputs: metrics.json, metrics.md, the plots and (``o.video``) the side-by-side video."""
    from facecapges.evaluation.report import markdown_table, markdown_unseen_table, write_metrics_json, write_report
    from facecapges.evaluation.timing import timing_markdown

    out, result, fps, sr, speaker = Path(o.out), paired.result, c.fps, c.sr, sel.speaker
    name, real0, methods0, audio0 = paired.first
    shown = {
        model_name: methods0[model_name],
        "random real segment": methods0["random real segment"],
        "mean pose": methods0["mean pose"],
    }
    files = write_report(
        out,
        result,
        real0,
        shown,
        audio0,
        sr,
        fps,
        title=f"Quantitative evaluation — {model_name}, speaker {speaker}",
        timeline_methods=[model_name],
    )
    full = {"paired": result, "unseen_audio": unseen, "warnings": warnings}
    write_metrics_json(full, out / "metrics.json")
    md = markdown_table(
        result,
        f"Quantitative evaluation — {model_name}, speaker {speaker}, {len(sel.evaluated)} clip(s) from frame "
        f"{sel.start}",
    )
    md += "\n".join(timing_markdown(result["timing"], "held-out frames")) + "\n"
    if unseen:
        md += markdown_unseen_table(unseen)
        for path, res in unseen.items():
            md += "\n".join(timing_markdown(res["timing"], Path(path).name)) + "\n"
    md += f"\n{fgd_line}\n"
    (out / "metrics.md").write_text(md)
    if o.video:
        files["video"] = _write_video(out, c, name, real0, methods0[model_name], model_name, audio0, not o.quiet)
    return files


def _write_video(out: Path, c, name: str, real0, gen0, model_name: str, audio0, progress: bool) -> str:
    """real_vs_generated.mp4: the first evaluated clip, real beside the model's first sample, with its audio."""
    import soundfile as sf

    from facecapges.avatar.render.skeleton_video import render_skeleton_video

    with tempfile.TemporaryDirectory() as td:
        wav = Path(td) / "audio.wav"
        sf.write(wav, audio0, c.sr)
        return str(
            render_skeleton_video(
                [real0, gen0],
                ["real", model_name],
                c.skeleton(name),
                out / "real_vs_generated.mp4",
                c.fps,
                wav,
                progress=progress,
            )
        )


def _check(o: EvalOptions) -> None:
    """The checks of ``o`` before anything is read: --offsets, the outputs (``o.force``), --split."""
    parse_offsets(o.offsets)  # a malformed --offsets before anything is read
    check_output_dir(
        o.out,
        ["metrics.json", "metrics.md", "beat_timeline.png", "joint_speed.png"]
        + (["real_vs_generated.mp4"] if o.video else []),
        o.force,
    )
    if o.split not in ("train", "val", "test", "all"):
        raise UserError(f"--split must be train, val, test or all, got {o.split!r}")


def run_eval(
    o: EvalOptions,
    say: Callable[[str], None] = echo,
    warn: Callable[[str], None] = echo_warning,
) -> dict:
    """Evaluate ``o.checkpoint`` on ``o.cache`` (see module docstring); returns files, warnings, timing.

    Every output in ``o.out`` is checked first (``o.force`` writes over them); ``warn`` gets the
    warnings, ``say`` the table and the files written. The phases: select clips, real pool, score
    paired, score unseen, write outputs."""
    from facecapges.data.cache import Cache

    _check(o)
    c = Cache(o.cache)  # a missing or malformed cache before torch and the checkpoint load
    from facecapges.evaluation.fgd import fgd_paths
    from facecapges.evaluation.timing import timing_section
    from facecapges.styles import load_style

    warnings: list[str] = []
    ckpt = load_style(o.checkpoint, o.style)
    fps, sr = c.fps, c.sr
    if abs(fps - ckpt.fps) > 1e-6:
        raise UserError(f"{o.cache}: the cache is at {fps:g} fps, the checkpoint runs at {ckpt.fps} fps")
    sel = _select_clips(o, c, ckpt, warnings)
    pool, training = _real_pool(c, sel, o.holdout_from, warnings)
    fgd, loc, fgd_source = _fgd_autoencoder(ckpt, o, say, warnings)
    weighted = all(sel.loaded[n]["semantic_present"] for n in sel.evaluated)
    if not weighted:
        warnings.append("not every evaluated clip has a semantic file: SRGR is unweighted")
    rng = np.random.default_rng(o.seed)
    paired, ms_all = _score_paired(o, c, ckpt, sel, pool, fgd, weighted, rng)
    result = paired.result
    skel = c.skeleton(sel.evaluated[0])
    realism = _realism(c, ckpt, paired, training, skel, o.seed)
    result["realism"] = realism(paired.shown_clips, paired.heldout_audio, no_classifier=["ground truth"])
    result["timing"] = timing_section(paired.shown_clips, paired.heldout_audio, sr, fps, skel, o.seed)
    result.update(
        checkpoint=str(ckpt.path),
        cache=str(o.cache),
        speaker=sel.speaker,
        clips=sel.evaluated,
        first_frame=sel.start,
        ms_per_frame=float(np.mean(ms_all)),
        fgd_autoencoder=str(fgd_paths(loc)[0]) if loc is not None else None,
        fgd_autoencoder_source=fgd_source,
    )
    unseen = _score_unseen(o, c, ckpt, sel.speaker, pool, fgd, skel, realism, rng, warnings) if o.audio else {}
    fgd_line = f"FGD autoencoder: {result['fgd_autoencoder']} ({fgd_source})" if loc is not None else "FGD: none"
    files = _write_outputs(o, c, ckpt.display_name, sel, paired, unseen, fgd_line, warnings)
    for w in warnings:
        warn(f"warning: {w}")
    say((Path(o.out) / "metrics.md").read_text())
    say("wrote " + ", ".join(files.values()))
    return {"files": files, "warnings": warnings, "ms_per_frame": result["ms_per_frame"]}
