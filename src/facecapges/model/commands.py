"""Commands of the model area: ``train``, ``generate``, ``styles``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer


def _load_clips(cache_path: Path, speaker: int, split: str):
    from facecapges.data.cache import Cache
    from facecapges.training.train import ClipArrays

    cache = Cache(cache_path)
    entries = cache.select(speaker, split)
    clips = []
    for e in entries:
        a = cache.load(e["name"])
        clips.append(ClipArrays(name=e["name"], pose=a["pose"], head=a["head"], face=a["face"], audio=a["audio"],
                                mask=a["mask"]))
    return cache, clips


def register(app: typer.Typer) -> None:
    @app.command()
    def train(
        cache: Path = typer.Option(..., help="A cache written by `facecapges prepare`."),
        speaker: int = typer.Option(..., help="BEAT speaker id: one checkpoint per speaker (thesis 3.2.2)."),
        out: Path = typer.Option(..., help="Run folder: last.pt, model.safetensors, log.csv."),
        config: Optional[Path] = typer.Option(None, help="YAML/JSON with 'model:' and 'train:' overrides."),
        epochs: Optional[int] = typer.Option(None, help="Number of epochs (default 375)."),
        split: Optional[str] = typer.Option(None, help="Clips to train on: train (default), val, test or all; "
                                                       "a resumed run keeps its own."),
        holdout_from: Optional[int] = typer.Option(None, help="Hold out frames >= this of every clip."),
        resume: bool = typer.Option(False, "--resume", help="Continue the run in OUT exactly where it stopped "
                                                            "(any number of processes)."),
        force: bool = typer.Option(False, "--force", help="Start over in a run folder that has a run."),
        device: str = typer.Option("auto", help="auto (a GPU when there is one), cpu or cuda; under torchrun "
                                                "each process takes GPU LOCAL_RANK."),
        amp: bool = typer.Option(False, "--amp", help="float16 mixed precision on GPU (no effect on CPU)."),
    ) -> None:
        """Train a FaceCapGes model with closed-loop sliding-window rollout (thesis ch. 4).

        Runs as is under `torchrun --nproc_per_node=K` (and multi-node): the global
        batch is train.batch_size x K and the learning rates scale with it; rank 0
        writes the run folder.
        """
        from facecapges.errors import UserError
        from facecapges.model.config import load_config_file
        from facecapges.training.distributed import init_distributed, shutdown
        from facecapges.training.train import build_trainer, load_resume

        ctx = init_distributed(device)
        try:
            say = typer.echo if ctx.is_main else (lambda *a, **k: None)

            def run_folder() -> tuple[str, dict | None]:  # rank 0's disk decides
                from facecapges.errors import check_output_dir
                from facecapges.training.resume_file import RunFolderLock

                if not resume and not (out / "last.pt").exists():  # a folder without a run keeps its files too
                    check_output_dir(out, ("model.safetensors", "log.csv", "summary.json"), force)
                check_output_dir(out)
                RunFolderLock(out).acquire()  # held until the process ends; a second train here is refused
                state = load_resume(out) if resume else None
                chosen = split if split is not None else (state["meta"].get("split", "train") if state else "train")
                if chosen not in ("train", "val", "test", "all"):
                    raise UserError(f"--split must be train, val, test or all, got {chosen!r}")
                if (out / "last.pt").exists() and not (resume or force):
                    raise UserError(f"{out}: holds a training run; pass --resume to continue it or --force to "
                                    "start over")
                return chosen, state

            chosen_split, state = ctx.run_on_main(run_folder)
            model_over, train_over = load_config_file(config) if config else ({}, {})
            if epochs is not None:
                if epochs < 1:
                    raise UserError("--epochs must be at least 1")
                train_over["epochs"] = epochs
            if holdout_from is not None:
                train_over["holdout_from"] = holdout_from
            cache_obj, clips = _load_clips(cache, speaker, chosen_split)
            if abs(cache_obj.fps - model_over.get("fps", 15)) > 1e-6:
                model_over["fps"] = int(round(cache_obj.fps))
            meta = {"speaker": speaker, "clips": [c.name for c in clips], "split": chosen_split,
                    "skeleton": cache_obj.index["skeleton"], "cache": str(cache)}
            if amp and ctx.device.type != "cuda":
                say("note: --amp is GPU-only; training on CPU in float32", err=True)
            trainer = build_trainer(clips, out, model_over, train_over, meta, resume, state=state, dist=ctx, amp=amp)
            say(f"training on {len(clips)} clip(s), {len(trainer.train_set)} segments"
                + (f", {len(trainer.held_set)} held-out" if trainer.held_set else "")
                + f"; epochs {trainer.epoch}/{trainer.tcfg.epochs}"
                + (f"; {ctx.world_size} processes, global batch {trainer.global_batch}, lr_g {trainer.lr_g:.3g}"
                   if ctx.enabled else ""))
            trainer.fit()
            say(f"checkpoint: {out / 'model.safetensors'}  log: {out / 'log.csv'}")
        finally:
            shutdown(ctx)

    @app.command()
    def generate(
        audio: Path = typer.Option(..., help="Speech audio (any format soundfile/ffmpeg reads; resampled to 16 kHz)."),
        out: Path = typer.Option(..., help="Output BVH file (full BEAT skeleton, model fps)."),
        face: Optional[Path] = typer.Option(None, help="BEAT-format face JSON, any fps (resampled)."),
        head: Optional[Path] = typer.Option(None, help="Head rotation .npy (T, 6) rot6d at the model fps."),
        checkpoint: Optional[Path] = typer.Option(None, help="Checkpoint file (default: the installed default style)."),
        style: Optional[str] = typer.Option(None, help="Installed style name (see `facecapges styles`)."),
        face_out: Optional[Path] = typer.Option(None, "--face-out", help="Also write the face to show with the "
                                                                          "motion (face JSON): --face resampled, or "
                                                                          "without --face, jaw and lips from the "
                                                                          "speech."),
        json_out: bool = typer.Option(False, "--json", help="Print a JSON summary instead of text."),
        vrma: Optional[Path] = typer.Option(None, "--vrma", help="Also write the gestures (+ the --face weights) "
                                                                 "as VRM Animation (.vrma) for any VRM avatar."),
        vrma_face: str = typer.Option("presets", "--vrma-face", help="Face in the .vrma: presets (VRM presets from "
                                                                     "ARKit, any VRM) or perfect-sync (52 ARKit)."),
        force: bool = typer.Option(False, "--force", help="Overwrite OUT if it exists."),
    ) -> None:
        """Generate upper-body gestures for a recording, frame by frame, no look-ahead."""
        import numpy as np

        from facecapges.errors import check_output_file
        from facecapges.io.bvh import BvhWriter
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.model.generate import generate_blocks, plan_inputs
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        check_output_file(out, force)  # before the work: existing, folder, unwritable
        if face_out is not None:
            check_output_file(face_out, force)
        if vrma is not None:
            from facecapges.avatar.vrma import check_face_mode

            check_output_file(vrma, force)
            check_face_mode(vrma_face)
        ckpt = load_checkpoint(checkpoint, style)
        inputs = plan_inputs(audio, face, head, fps=ckpt.fps)
        for note in inputs.notes:
            typer.secho(f"warning: {note}", err=True, fg=typer.colors.YELLOW)
        skel = ckpt.skeleton
        timing_ms: list[float] = []
        mouth = None
        if face_out is not None and face is None:  # no face track: jaw and lips from the speech
            from facecapges.capture.speech_mouth import SpeechMouth

            mouth, spoken = SpeechMouth(ckpt.fps), []

        def blocks():
            for a, f, h in inputs.blocks():
                if mouth is not None:
                    spoken.extend(mouth.step(x) for x in a)
                yield a, f, h

        kept = []  # the poses, only when a .vrma is asked for
        with BvhWriter(out, skel, inputs.n_frames, ckpt.fps) as bvh:  # block by block: memory flat in length
            for poses in generate_blocks(ckpt, blocks(), inputs.n_frames, ckpt.fps, not json_out, timing_ms):
                bvh.write(pose_to_motion(skel, normalize_rot6d(poses)))
                if vrma is not None:
                    kept.append(normalize_rot6d(poses))
        if face_out is not None:
            from facecapges.io.face_json import write_face_json

            shown = inputs.face if mouth is None else np.stack(spoken).astype(np.float32)
            write_face_json(face_out, shown, ckpt.fps, inputs.head)
        if vrma is not None:
            from facecapges.avatar.vrma import write_pose_vrma

            write_pose_vrma(vrma, skel, np.concatenate(kept), ckpt.fps, inputs.face if face else None, vrma_face)
            typer.echo(f"wrote {vrma} (VRM Animation)", err=json_out)
        ms, n = timing_ms[0], inputs.n_frames
        summary = {"out": str(out), "frames": int(n), "fps": ckpt.fps,
                   "duration_s": round(n / ckpt.fps, 3), "ms_per_frame": round(ms, 3),
                   "checkpoint": str(ckpt.path), "warnings": inputs.notes}
        if json_out:
            typer.echo(json.dumps(summary))
        else:
            typer.echo(f"wrote {out}: {summary['frames']} frames at {ckpt.fps} fps "
                       f"({summary['duration_s']} s), {ms:.2f} ms/frame")

    @app.command()
    def styles(json_out: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
        """List the installed speaking styles (per-speaker checkpoints)."""
        from facecapges.model.checkpoint import DEFAULT_STYLE, list_styles, load_checkpoint

        rows = []
        for name, path in list_styles().items():
            meta = load_checkpoint(path).meta
            rows.append({"name": name, "default": name == DEFAULT_STYLE, "speaker": meta.get("speaker"),
                         "epochs": meta.get("epochs_trained"), "path": str(path)})
        if json_out:
            typer.echo(json.dumps(rows, indent=2))
            return
        if not rows:
            typer.echo("no styles installed")
        for r in rows:
            typer.echo(f"{'*' if r['default'] else ' '} {r['name']}  speaker {r['speaker']}  "
                       f"{r['epochs']} epochs  {r['path']}")
