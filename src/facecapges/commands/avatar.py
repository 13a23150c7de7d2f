"""Commands of the avatar area: ``blendshapes``, ``avatar build``, ``render``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.avatar.render.motion_file import RenderOptions
from facecapges.commands.params import FORCE_OUT


def _skeleton(bvh: Path | None):
    """The BEAT skeleton from ``bvh``, else the one stored with the default checkpoint."""
    from facecapges.errors import UserError

    if bvh is not None:
        from facecapges.io.bvh import read_bvh

        return read_bvh(bvh).skeleton, str(bvh)
    from facecapges.styles import load_skeleton

    try:
        return load_skeleton(), "the default checkpoint"
    except UserError as exc:
        raise UserError(
            f"no skeleton given and the default checkpoint has none ({exc}); pass --skeleton FILE.bvh (any BEAT BVH)"
        ) from None


MESH = typer.Option("--mesh", help="Neutral triangle mesh (.obj, an oriented manifold).")
CONTROLS = typer.Option("--controls", help="Control table JSON (control vertices and per-target displacements).")
BLENDSHAPES_OUT = typer.Option("--out", help="Output directory: one OBJ per target + report.json.")
NO_AOI = typer.Option("--no-aoi", help="Deform without areas of influence (D = I).")
BLENDSHAPES_FORCE = typer.Option("--force", help="Overwrite files already in --out.")


def blendshapes_cmd(
    mesh: Annotated[Path, MESH],
    controls: Annotated[Path, CONTROLS],
    out: Annotated[Path, BLENDSHAPES_OUT],
    no_aoi: Annotated[bool, NO_AOI] = False,
    force: Annotated[bool, BLENDSHAPES_FORCE] = False,
) -> None:
    """Generate the 52 ARKit blendshape targets by Laplacian deformation with areas of influence."""
    import json
    import time

    from facecapges.avatar.blendshape_table import load_table
    from facecapges.avatar.blendshapes import build_blendshapes
    from facecapges.avatar.mesh import TriMesh, check_manifold, read_obj, write_obj
    from facecapges.errors import refuse_overwrite
    from facecapges.progress import Progress

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


AVATAR_BUILD_OUT = typer.Option("--out", help="Output file (.glb, or .vrm with --format vrm / vrm0).")
SKELETON = typer.Option(
    "--skeleton",
    help="A BEAT BVH whose hierarchy and rest offsets to use (default: the skeleton stored with the default model).",
)
FMT = typer.Option(
    "--format",
    help="glb (glTF 2.0), vrm (VRM 1.0: humanoid bones, VRM "
    "presets + 52 ARKit perfect-sync expressions, lookAt, "
    "licence) or vrm0 (the same as VRM 0.x, for apps that "
    "read only 0.x, such as VSeeFace).",
)


def avatar_build(
    out: Annotated[Path, AVATAR_BUILD_OUT],
    skeleton: Annotated[Path | None, SKELETON] = None,
    fmt: Annotated[str, FMT] = "glb",
    force: Annotated[bool, FORCE_OUT] = False,
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
        from facecapges.avatar.vrm.write import write_vrm

        write_vrm(av, out, "0.x" if fmt == "vrm0" else "1.0")
    else:
        write_glb(av, out)
    typer.echo(
        f"{out}: {av.info['joints']} joints (skeleton from {source}), {av.info['body_vertices']} body + "
        f"{av.info['face_vertices']} face vertices, {av.info['morph_targets']} morph targets"
    )


AVATAR_VRMA_BVH = typer.Option("--bvh", help="Motion (BEAT skeleton BVH), e.g. a run's motion.bvh.")
AVATAR_VRMA_OUT = typer.Option("--out", help="Output .vrma (VRM Animation 1.0).")
AVATAR_VRMA_FACE = typer.Option("--face", help="Face JSON to add as expressions (resampled to the BVH).")
FACE_MODE = typer.Option(
    "--vrma-face", help="presets (VRM presets from ARKit, any VRM) or perfect-sync (52 ARKit expressions)."
)


def avatar_vrma(
    bvh: Annotated[Path, AVATAR_VRMA_BVH],
    out: Annotated[Path, AVATAR_VRMA_OUT],
    face: Annotated[Path | None, AVATAR_VRMA_FACE] = None,
    face_mode: Annotated[str, FACE_MODE] = "presets",
    force: Annotated[bool, FORCE_OUT] = False,
) -> None:
    """Convert a BVH (+ face JSON) to VRM Animation, playable on any VRM avatar."""
    from facecapges.avatar.body import check_skeleton
    from facecapges.avatar.vrm.animation import check_face_mode, write_bvh_as_vrma
    from facecapges.errors import echo_warning, refuse_overwrite, require_file
    from facecapges.io.bvh import read_bvh

    refuse_overwrite(out, force)
    check_face_mode(face_mode)
    motion = read_bvh(require_file(bvh, "BVH"))
    check_skeleton(motion.skeleton, str(bvh))
    if face is not None:
        from facecapges.io.face_json import read_face_json

        track = read_face_json(require_file(face, "face JSON"))
        motion_s, face_s = len(motion.motion) / motion.fps, track.n_frames / track.fps
        if abs(motion_s - face_s) > max(0.5, 0.05 * motion_s):  # not the same recording, or cut differently
            rest = (
                f"the face holds its last frame for the last {motion_s - face_s:.1f} s"
                if face_s < motion_s
                else (f"the face's last {face_s - motion_s:.1f} s are left out")
            )
            echo_warning(
                f"warning: {face} lasts {face_s:.1f} s but {bvh} {motion_s:.1f} s; {rest} (are they one recording?)"
            )
    p = write_bvh_as_vrma(bvh, out, face, face_mode)
    typer.echo(f"{p}: VRM Animation, {p.stat().st_size} bytes")


RENDER_BVH = typer.Option("--bvh", help="Motion (BEAT skeleton BVH).")
RENDER_OUT = typer.Option("--out", help="Output .mp4.")
RENDER_FACE = typer.Option(
    "--face",
    help="Face JSON ({'names', 'frames': [{'time', 'weights'}]}); without it, the jaw and lips follow --audio.",
)
AUDIO = typer.Option("--audio", help="Audio to mux into the video (wav or any ffmpeg input).")
AVATAR_GLB = typer.Option(
    "--avatar",
    help="Avatar: a VRM 0.x/1.0 (.vrm), a GLB with a humanoid "
    "skeleton, or our .glb (default: built from the "
    "BVH's skeleton).",
)
CONTACT_SHEET = typer.Option("--contact-sheet", help="Also write a PNG of all 52 blendshapes.")
SIZE = typer.Option("--size", help="Video size WIDTHxHEIGHT.")
RENDER_FORCE = typer.Option("--force", help="Overwrite outputs that exist.")


def render_cmd(
    bvh: Annotated[Path, RENDER_BVH],
    out: Annotated[Path, RENDER_OUT],
    face: Annotated[Path | None, RENDER_FACE] = None,
    audio: Annotated[Path | None, AUDIO] = None,
    avatar_glb: Annotated[Path | None, AVATAR_GLB] = None,
    contact_sheet: Annotated[Path | None, CONTACT_SHEET] = None,
    size: Annotated[str, SIZE] = RenderOptions.size,
    force: Annotated[bool, RENDER_FORCE] = RenderOptions.force,
) -> None:
    """Render the avatar (front view) driven by a BVH and optional face weights, with the audio muxed."""
    options = RenderOptions(**locals())  # before any other name is bound here
    from facecapges.avatar.render.motion_file import render_motion_file

    render_motion_file(options, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("blendshapes")(blendshapes_cmd)
    avatar = typer.Typer(
        help="Build the avatar (skinned BEAT body + 52-blendshape face) as glTF.", no_args_is_help=True
    )
    app.add_typer(avatar, name="avatar")
    avatar.command("build")(avatar_build)
    avatar.command("vrma")(avatar_vrma)
    app.command("render")(render_cmd)
