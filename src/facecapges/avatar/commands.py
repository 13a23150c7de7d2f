"""Commands of the avatar area: ``blendshapes``, ``avatar build``, ``render``."""

from __future__ import annotations

from pathlib import Path

import typer


def _skeleton(bvh: Path | None):
    """The BEAT skeleton from ``bvh``, else the one stored with the default checkpoint."""
    from facecapges.errors import UserError

    if bvh is not None:
        from facecapges.io.bvh import read_bvh

        return read_bvh(bvh).skeleton, str(bvh)
    from facecapges.model.checkpoint import load_skeleton

    try:
        return load_skeleton(), "the default checkpoint"
    except UserError as exc:
        raise UserError(
            f"no skeleton given and the default checkpoint has none ({exc}); pass --skeleton FILE.bvh (any BEAT BVH)"
        ) from None


def register(app: typer.Typer) -> None:
    @app.command("blendshapes")
    def blendshapes_cmd(
        mesh: Path = typer.Option(..., "--mesh", help="Neutral triangle mesh (.obj, an oriented manifold)."),
        controls: Path = typer.Option(
            ..., "--controls", help="Control table JSON (control vertices and per-target displacements)."
        ),
        out: Path = typer.Option(..., "--out", help="Output directory: one OBJ per target + report.json."),
        no_aoi: bool = typer.Option(False, "--no-aoi", help="Deform without areas of influence (D = I)."),
        force: bool = typer.Option(False, "--force", help="Overwrite files already in --out."),
    ) -> None:
        """Generate the 52 ARKit blendshape targets by Laplacian deformation with areas of influence."""
        import json
        import time

        from rich.progress import Progress

        from facecapges.avatar.blendshape_table import load_table
        from facecapges.avatar.blendshapes import build_blendshapes
        from facecapges.avatar.mesh import TriMesh, check_manifold, read_obj, write_obj
        from facecapges.errors import refuse_overwrite

        neutral = read_obj(mesh)
        check_manifold(neutral, mesh)
        table = load_table(controls, neutral.n_vertices)
        out.mkdir(parents=True, exist_ok=True)
        paths = {n: out / f"{n}.obj" for n in table.names}
        for p in [*paths.values(), out / "report.json"]:
            refuse_overwrite(p, force)
        t0 = time.perf_counter()
        with Progress(transient=True) as bar:
            task = bar.add_task("deforming", total=len(table.names))
            shapes = build_blendshapes(neutral, table, aoi=not no_aoi, progress=lambda k: bar.advance(task))
        elapsed = time.perf_counter() - t0
        for k, n in enumerate(shapes.names):
            write_obj(paths[n], TriMesh(shapes.targets[k], neutral.faces), header=f"blendshape {n} of {mesh.name}")
        report = {"mesh": str(mesh), "controls": str(controls), "seconds": elapsed, **shapes.report}
        (out / "report.json").write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
        r = shapes.report
        typer.echo(
            f"{len(shapes.names)} targets in {elapsed:.2f} s → {out}; control error {r['max_control_error']:.2e} "
            f"of face size"
        )
        if "mean_far_motion_aoi" in r:
            typer.echo(
                f"far-vertex motion (mean, fraction of face size): with AOI {r['mean_far_motion_aoi']:.2e}, "
                f"without AOI {r['mean_far_motion_no_aoi']:.2e}, plain edit {r['mean_far_motion_plain']:.2e}"
            )

    avatar = typer.Typer(
        help="Build the avatar (skinned BEAT body + 52-blendshape face) as glTF.", no_args_is_help=True
    )
    app.add_typer(avatar, name="avatar")

    @avatar.command("build")
    def avatar_build(
        out: Path = typer.Option(..., "--out", help="Output file (.glb, or .vrm with --format vrm / vrm0)."),
        skeleton: Path = typer.Option(
            None,
            "--skeleton",
            help="A BEAT BVH whose hierarchy and rest offsets to use "
            "(default: the skeleton stored with the default model).",
        ),
        fmt: str = typer.Option(
            "glb",
            "--format",
            help="glb (glTF 2.0), vrm (VRM 1.0: humanoid bones, VRM "
            "presets + 52 ARKit perfect-sync expressions, lookAt, "
            "licence) or vrm0 (the same as VRM 0.x, for apps that "
            "read only 0.x, such as VSeeFace).",
        ),
        force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
    ) -> None:
        """Write the avatar: procedural upper body skinned to the BEAT skeleton, face with 52 ARKit morph targets."""
        from facecapges.avatar.body import default_avatar
        from facecapges.avatar.gltf import write_glb
        from facecapges.errors import UserError, check_output_file

        if fmt not in ("glb", "vrm", "vrm0"):
            raise UserError(f"--format must be glb, vrm or vrm0, got {fmt!r}")
        check_output_file(out, force)
        skel, source = _skeleton(skeleton)
        av = default_avatar(skel)
        out.parent.mkdir(parents=True, exist_ok=True)
        if fmt in ("vrm", "vrm0"):
            from facecapges.avatar.vrm import write_vrm

            write_vrm(av, out, "0.x" if fmt == "vrm0" else "1.0")
        else:
            write_glb(av, out)
        typer.echo(
            f"{out}: {av.info['joints']} joints (skeleton from {source}), {av.info['body_vertices']} body + "
            f"{av.info['face_vertices']} face vertices, {av.info['morph_targets']} morph targets"
        )

    @avatar.command("vrma")
    def avatar_vrma(
        bvh: Path = typer.Option(..., "--bvh", help="Motion (BEAT skeleton BVH), e.g. a run's motion.bvh."),
        out: Path = typer.Option(..., "--out", help="Output .vrma (VRM Animation 1.0)."),
        face: Path = typer.Option(None, "--face", help="Face JSON to add as expressions (resampled to the BVH)."),
        face_mode: str = typer.Option(
            "presets",
            "--vrma-face",
            help="presets (VRM presets from ARKit, any VRM) or perfect-sync (52 ARKit expressions).",
        ),
        force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
    ) -> None:
        """Convert a BVH (+ face JSON) to VRM Animation, playable on any VRM avatar."""
        from facecapges.avatar.body import check_skeleton
        from facecapges.avatar.vrma import check_face_mode, write_bvh_as_vrma
        from facecapges.errors import refuse_overwrite, require_file
        from facecapges.io.bvh import read_bvh

        refuse_overwrite(out, force)
        check_face_mode(face_mode)
        check_skeleton(read_bvh(require_file(bvh, "BVH")).skeleton, str(bvh))
        if face is not None:
            require_file(face, "face JSON")
        p = write_bvh_as_vrma(bvh, out, face, face_mode)
        typer.echo(f"{p}: VRM Animation, {p.stat().st_size} bytes")

    @app.command("render")
    def render_cmd(
        bvh: Path = typer.Option(..., "--bvh", help="Motion (BEAT skeleton BVH)."),
        out: Path = typer.Option(..., "--out", help="Output .mp4."),
        face: Path = typer.Option(
            None,
            "--face",
            help="Face JSON ({'names', 'frames': [{'time', 'weights'}]}); without it, the jaw and lips follow --audio.",
        ),
        audio: Path = typer.Option(None, "--audio", help="Audio to mux into the video (wav or any ffmpeg input)."),
        avatar_glb: Path = typer.Option(
            None,
            "--avatar",
            help="Avatar: a VRM 0.x/1.0 (.vrm), a GLB with a humanoid "
            "skeleton, or our .glb (default: built from the "
            "BVH's skeleton).",
        ),
        contact_sheet: Path = typer.Option(None, "--contact-sheet", help="Also write a PNG of all 52 blendshapes."),
        size: str = typer.Option("640x480", help="Video size WIDTHxHEIGHT."),
        force: bool = typer.Option(False, "--force", help="Overwrite outputs that exist."),
    ) -> None:
        """Render the avatar (front view) driven by a BVH and optional face weights, with the audio muxed."""
        import numpy as np

        from facecapges.arkit import ARKIT_NAMES
        from facecapges.avatar.body import check_skeleton, default_avatar
        from facecapges.avatar.gltf import avatar_to_gltf
        from facecapges.avatar.render.video import bvh_quaternions, render_video
        from facecapges.avatar.render.video import contact_sheet as make_sheet
        from facecapges.errors import UserError, check_output_file, file_error, require_file
        from facecapges.io.bvh import read_bvh

        check_output_file(out, force)
        if contact_sheet is not None:
            check_output_file(contact_sheet, force)
        if audio is not None:  # used only at the final mux: check it before the whole render
            from facecapges.io.audio import check_audio

            check_audio(audio)
        try:
            width, height = (int(x) for x in size.lower().split("x"))
        except ValueError:
            raise UserError(f"--size must be WIDTHxHEIGHT, got {size!r}") from None
        if not (16 <= width <= 4096 and 16 <= height <= 4096):
            raise UserError(f"--size {size} is out of range")
        motion = read_bvh(bvh)
        check_skeleton(motion.skeleton, str(bvh))
        if audio is not None:
            require_file(audio, "audio")
        if face is not None:
            require_file(face, "face JSON")
        from facecapges.avatar.vrm_view import face_weights as _face_weights
        from facecapges.avatar.vrm_view import is_vrm_file

        def _shown_face(T: int):
            """The face JSON's weights; without one, jaw and lips from the speech (capture.speech_mouth)."""
            if face is None and audio is not None:
                from facecapges.capture.speech_mouth import speech_frames, speech_mouth_track
                from facecapges.io.audio import load_audio

                return speech_mouth_track(speech_frames(load_audio(audio), motion.fps, T), motion.fps)
            return _face_weights(face, motion.fps, T)

        if avatar_glb is not None and is_vrm_file(require_file(avatar_glb, "avatar")):
            from facecapges.avatar.vrm_view import VrmDriver, bvh_local_matrices, render_vrm_video

            driver = VrmDriver.from_file(avatar_glb, motion.skeleton)
            typer.echo(f"avatar: {driver.describe()}")
            if contact_sheet is not None:
                raise UserError("--contact-sheet needs our own avatar (its 52 morph targets), not a VRM")
            weights = _shown_face(len(motion.motion))
            figures = render_vrm_video(
                driver,
                bvh_local_matrices(motion.skeleton, motion.motion),
                weights,
                motion.fps,
                out,
                audio=audio,
                width=width,
                height=height,
            )
            typer.echo(
                f"{out}: {figures['frames']} frames at {motion.fps:g} fps rendered in {figures['total_s']:.1f} s"
            )
            return
        if avatar_glb is not None:
            import pygltflib

            p = require_file(avatar_glb, "avatar")
            try:
                glb = p.read_bytes()
                doc = pygltflib.GLTF2.load_from_bytes(glb)
                joint_names = doc.extras["facecapges"]["joint_names"]
            except Exception as exc:  # noqa: BLE001 - any parse failure is the user's file
                raise file_error(p, f"not a facecapges avatar .glb ({exc})") from None
        else:
            doc = avatar_to_gltf(default_avatar(motion.skeleton))
            glb = b"".join(doc.save_to_bytes())
            joint_names = list(motion.skeleton.names)
        quats = bvh_quaternions(joint_names, motion.skeleton, motion.motion, str(bvh))
        weights = _shown_face(quats.shape[0])
        figures = render_video(
            glb, quats, np.clip(weights, 0.0, 1.0), motion.fps, out, audio=audio, width=width, height=height
        )
        typer.echo(f"{out}: {figures['frames']} frames at {motion.fps:g} fps rendered in {figures['total_s']:.1f} s")
        if contact_sheet is not None:
            make_sheet(glb, list(ARKIT_NAMES), contact_sheet)
            typer.echo(f"{contact_sheet}: contact sheet of the 52 blendshapes")
