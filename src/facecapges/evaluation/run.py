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


def run_eval(
    o: EvalOptions,
    say: Callable[[str], None] = echo,
    warn: Callable[[str], None] = echo_warning,
) -> dict:
    """Evaluate ``o.checkpoint`` on ``o.cache`` (see module docstring); returns files, warnings, timing.

    Every output in ``o.out`` is checked first (``o.force`` writes over them); ``warn`` gets the
    warnings, ``say`` the table and the files written."""
    from facecapges.data.cache import Cache

    cache, out, speaker, split, holdout_from = o.cache, o.out, o.speaker, o.split, o.holdout_from
    seed, samples, progress, offsets_s = o.seed, o.samples, not o.quiet, parse_offsets(o.offsets)

    check_output_dir(
        out,
        ["metrics.json", "metrics.md", "beat_timeline.png", "joint_speed.png"]
        + (["real_vs_generated.mp4"] if o.video else []),
        o.force,
    )
    if split not in ("train", "val", "test", "all"):
        raise UserError(f"--split must be train, val, test or all, got {split!r}")
    c = Cache(cache)  # a missing or malformed cache before torch and the checkpoint load
    from facecapges.engine.generate import generate_poses
    from facecapges.evaluation import baselines as bl
    from facecapges.evaluation.fgd import fgd_paths, find_fgd, load_fgd
    from facecapges.evaluation.realism import realism_section
    from facecapges.evaluation.report import markdown_table, markdown_unseen_table, write_metrics_json, write_report
    from facecapges.evaluation.suite import Method, PairedClips, evaluate_unpaired
    from facecapges.evaluation.timing import timing_markdown, timing_section
    from facecapges.styles import load_style

    warnings: list[str] = []
    ckpt = load_style(o.checkpoint, o.style)
    model_name = ckpt.display_name
    fps, sr = c.fps, c.sr
    if abs(fps - ckpt.fps) > 1e-6:
        raise UserError(f"{cache}: the cache is at {fps:g} fps, the checkpoint runs at {ckpt.fps} fps")
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
            f"{cache}: no {split!r} clips of speaker {speaker} to evaluate (speaker/split pairs: {have}); "
            "use --holdout-from FRAME to evaluate the end of every clip"
        )
    loaded = {e["name"]: c.load(e["name"]) for e in entries}
    min_frames = 32
    evaluated = [n for n in loaded if len(loaded[n]["pose"]) - start >= min_frames]
    for n in loaded:
        if n not in evaluated:
            warnings.append(f"clip {n}: fewer than {min_frames} frames from frame {start} on; not evaluated")
    if samples < 1:
        raise UserError("--samples must be at least 1")
    if not evaluated:
        raise UserError(
            f"{cache}: no clip of speaker {speaker} has {min_frames} frames to evaluate from frame {start} on"
        )
    # the real pool for the baselines
    if holdout_from is not None:
        pool = [loaded[n]["pose"][:holdout_from] for n in loaded]
    else:
        pool = [c.load(e["name"])["pose"] for e in c.clips(speaker=speaker, split="train") if e["name"] not in loaded]
    training = list(pool)  # the speaker's training frames (empty when the cache has none outside the evaluated clips)
    if holdout_from is None and not pool:
        warnings.append(
            f"no train clips of speaker {speaker} outside the evaluated ones: mean pose and random "
            "segment come from the evaluated clips"
        )
        pool = [loaded[n]["pose"] for n in evaluated]
    # FGD autoencoder
    fgd = None
    loc, fgd_source = find_fgd(ckpt.path, o.fgd)
    if loc is not None:
        fgd = load_fgd(loc)
        say(f"FGD autoencoder: {fgd_paths(loc)[0]} ({fgd_source})")
    else:
        warnings.append(
            f"no FGD autoencoder ({fgd_source}): FGD not computed (train one with "
            f"`facecapges fgd-train --checkpoint {ckpt.path}`)"
        )
    weighted = all(loaded[n]["semantic_present"] for n in evaluated)
    if not weighted:
        warnings.append("not every evaluated clip has a semantic file: SRGR is unweighted")
    rng = np.random.default_rng(seed)
    scored, ms_all = PairedClips(sr, fps, offsets_s, progress), []
    shown_clips: dict[str, list[np.ndarray]] = {}  # each method's first sample per clip, for the realism section
    heldout_real: list[np.ndarray] = []
    heldout_audio: list[np.ndarray] = []
    first: tuple[str, np.ndarray, dict[str, np.ndarray], np.ndarray] | None = None  # its first sample per method
    for name in evaluated:
        a = loaded[name]
        real, audio, inputs = heldout_inputs(a, start, fps, sr, ckpt.meta.get("head_reference_rot6d"))
        gen, ms = generate_poses(ckpt, inputs, progress=progress)
        ms_all.append(ms)
        gens = [gen] + [
            generate_poses(ckpt, inputs, progress, _real_window(pool, history_frames(ckpt), rng))[0]
            for _ in range(samples - 1)
        ]
        if holdout_from is not None:
            seg_pool, excl = [a["pose"]], (0, start, len(a["pose"]))
        else:
            seg_pool, excl = pool, None
        try:
            segment = bl.random_segment(seg_pool, len(real), rng, exclude=excl)
        except ValueError:
            try:
                segment = bl.random_segment(
                    pool + [a["pose"]], len(real), rng, exclude=(len(pool), start, len(a["pose"]))
                )
            except ValueError:
                raise UserError(
                    f"clip {name}: {len(real)} frames from frame {start} on, but no real stretch that long outside "
                    "them for the random real segment; use a later --holdout-from"
                ) from None
        methods: dict[str, Method] = {
            "ground truth": bl.ground_truth(real),
            "mean pose": bl.mean_pose_sequence(pool, len(real)),
            "random real segment": segment,
            model_name: gens,
        }
        scored.add(real, methods, audio, a["semantic"][start:] if weighted else None, c.skeleton(name))
        heldout_real.append(real)
        heldout_audio.append(audio)
        for k, v in methods.items():
            shown_clips.setdefault(k, []).append(v if isinstance(v, np.ndarray) else v[0])
        if first is None:
            first = (name, real, {k: v if isinstance(v, np.ndarray) else v[0] for k, v in methods.items()}, audio)
    result = scored.combine(fgd)
    skel = c.skeleton(evaluated[0])
    database, db_source = engine_database(ckpt, training)
    reference = training or heldout_real
    realism = functools.partial(
        realism_section,
        sr=sr,
        fps=fps,
        skeleton=skel,
        real_heldout=heldout_real,
        reference=reference,
        database=database,
        database_source=db_source,
        seed=seed,
        control_reference=training or None,  # no other real motion of the speaker: no control
        reference_source="the speaker's training motion"
        if training
        else "the evaluated real motion (no training frames)",
    )
    result["realism"] = realism(shown_clips, heldout_audio, no_classifier=["ground truth"])
    result["timing"] = timing_section(shown_clips, heldout_audio, sr, fps, skel, seed)
    result.update(
        checkpoint=str(ckpt.path),
        cache=str(cache),
        speaker=speaker,
        clips=evaluated,
        first_frame=start,
        ms_per_frame=float(np.mean(ms_all)),
        fgd_autoencoder=str(fgd_paths(loc)[0]) if loc is not None else None,
        fgd_autoencoder_source=fgd_source,
    )
    # unseen audio
    unseen = {}
    if o.audio:
        from facecapges.io.audio import load_audio

        all_real = [c.load(e["name"])["pose"] for e in c.clips(speaker=speaker)]  # every real clip
        for path in o.audio:
            inputs = ckpt.prepare_inputs(path)
            warnings += inputs.notes
            gen, _ = generate_poses(ckpt, inputs, progress=progress)
            gens = [gen] + [
                generate_poses(ckpt, inputs, progress, _real_window(pool, history_frames(ckpt), rng))[0]
                for _ in range(samples - 1)
            ]
            wav = load_audio(path, sr)
            res = evaluate_unpaired(
                {model_name: gens},
                wav,
                sr,
                fps,
                fgd=fgd,
                fgd_reference=all_real,
                offsets_s=offsets_s,
                progress=progress,
                skeleton=skel,
            )
            res["realism"] = realism({model_name: [gens[0]]}, [wav])
            res["timing"] = timing_section({model_name: [gens[0]]}, [wav], sr, fps, skel, seed)
            unseen[str(path)] = res
    out = Path(out)
    assert first is not None  # at least one clip was evaluated
    name, real0, methods0, audio0 = first
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
        f"Quantitative evaluation — {model_name}, speaker {speaker}, {len(evaluated)} clip(s) from frame {start}",
    )
    md += "\n".join(timing_markdown(result["timing"], "held-out frames")) + "\n"
    if unseen:
        md += markdown_unseen_table(unseen)
        for path, res in unseen.items():
            md += "\n".join(timing_markdown(res["timing"], Path(path).name)) + "\n"
    fgd_line = f"FGD autoencoder: {result['fgd_autoencoder']} ({fgd_source})" if loc is not None else "FGD: none"
    md += f"\n{fgd_line}\n"
    (out / "metrics.md").write_text(md)
    if o.video:
        import soundfile as sf

        from facecapges.avatar.render.skeleton_video import render_skeleton_video

        with tempfile.TemporaryDirectory() as td:
            wav = Path(td) / "audio.wav"
            sf.write(wav, audio0, sr)
            files["video"] = str(
                render_skeleton_video(
                    [real0, methods0[model_name]],
                    ["real", model_name],
                    c.skeleton(name),
                    out / "real_vs_generated.mp4",
                    fps,
                    wav,
                    progress=progress,
                )
            )
    for w in warnings:
        warn(f"warning: {w}")
    say((out / "metrics.md").read_text())
    say("wrote " + ", ".join(files.values()))
    return {"files": files, "warnings": warnings, "ms_per_frame": result["ms_per_frame"]}
