"""A study folder: what ``facecapges study create`` writes and ``serve``/``analyze`` read.

Layout of ``STUDY_DIR``::

    study.json                      design: systems, clips (frames, fps, duration), criteria,
                                    seed and every participant's plan (facecapges.study.design)
    avatar.glb                      the avatar (facecapges.avatar), built from the first BVH's skeleton
    avatar.vrm                      instead, with ``study create --avatar FILE.vrm``: that VRM / humanoid GLB;
                                    then motion files hold its normalised humanoid bones ("bone_names",
                                    facecapges.avatar.retarget) and face.json its expressions
    media/<clip>/audio.wav          the clip's speech, 16 kHz mono PCM16 (transcoded from any input)
    media/<clip>/face.json          {"fps", "frames", "names": 52 ARKit names, "weights": T*52 numbers}
    media/<clip>/motion-<system>.json
                                    {"fps", "frames", "joint_names", "quats": T*J*4 numbers}
    responses/<participant>.json    the answers (facecapges.study.store)
    invitations.txt                 one invitation link per participant (``/?invite=TOKEN``)

Invitations: every participant gets an unguessable token (:func:`new_token`, 128 random
bits from :mod:`secrets`, not derived from the seed), stored in the plan. The server
takes answers only with a participant's token, so knowing the ids ``P01…`` is not
enough to answer for someone; the organiser hands each participant his link.

Poses are the LOCAL joint rotations as (w, x, y, z) quaternions per BEAT joint, in the
BVH's joint order (= the avatar's, see src/facecapges/web/avatar_scene.js), at the study
frame rate: each BVH is resampled from its own rate with
:func:`facecapges.timing.resample` and cut or held at its last frame to the clip's
``round(duration · fps)`` frames (the length check of :mod:`facecapges.study.clips`
keeps that to at most ``tolerance_frames``). The face weights get the same treatment
(neutral when the clip has no face track). Numbers are rounded to 4 decimals.

The files are named after systems, so the server never serves them by name: a
participant's page only ever sees screen positions (facecapges.study.server).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from facecapges.errors import UserError, file_error
from facecapges.study.criteria import CRITERIA
from facecapges.study.design import StudyPlan, balance_report, make_plan, new_token
from facecapges.study.options import StudyCreateOptions

STUDY_FILE = "study.json"
AVATAR_FILE = "avatar.glb"
VRM_FILE = "avatar.vrm"
FORMAT = "facecapges-study/1"


def _fit(frames: np.ndarray, n: int) -> np.ndarray:
    """Cut ``frames`` to ``n`` rows or repeat its last row up to ``n``."""
    if len(frames) >= n:
        return frames[:n]
    return np.concatenate([frames, np.repeat(frames[-1:], n - len(frames), axis=0)], axis=0)


def _numbers(a: np.ndarray, decimals: int = 4) -> list:
    return np.round(np.asarray(a, np.float64).ravel(), decimals).tolist()


def media_dir(study_dir: Path, clip: str) -> Path:
    return Path(study_dir) / "media" / clip


def motion_file(study_dir: Path, clip: str, system: str) -> Path:
    return media_dir(study_dir, clip) / f"motion-{system}.json"


INVITATIONS_FILE = "invitations.txt"


def write_private(path: Path, text: str) -> Path:
    """Write ``text`` atomically to ``path``, readable by its owner only (0600: it holds participant tokens)."""
    import os

    tmp = path.with_name(path.name + ".part")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(text)
    os.chmod(tmp, 0o600)  # whatever the umask
    tmp.replace(path)
    return path


def write_invitations(study_dir: Path, plan: StudyPlan, base_url: str = "http://127.0.0.1:8770") -> Path:
    """``invitations.txt``: one line per participant, ``ID  URL/?invite=TOKEN`` (written atomically)."""
    f = Path(study_dir) / INVITATIONS_FILE
    lines = [
        "# one link per participant; each link is that participant's only credential",
        *(f"{p.id}\t{base_url.rstrip('/')}/?invite={p.token}" for p in plan.participants),
    ]
    write_private(f, "\n".join(lines) + "\n")
    return f


def ensure_tokens(study: Study) -> int:
    """Give every participant without a token one and save the plan; returns how many were added.

    For a study made before invitations: answers already in it carry no token and are
    left out of the analysis (facecapges.study.analyze).
    """
    missing = [p for p in study.plan.participants if not p.token]
    for p in missing:
        p.token = new_token()
    if missing:
        study.doc["plan"] = study.plan.to_json()
        write_private(study.dir / STUDY_FILE, json.dumps(study.doc, indent=1) + "\n")
    return len(missing)


def create_study(
    clips_yaml: str | Path,
    out: str | Path,
    n_participants: int | None = StudyCreateOptions.participants,
    seed: int = StudyCreateOptions.seed,
    force: bool = StudyCreateOptions.force,
    progress: bool = True,
    avatar: str | Path | None = StudyCreateOptions.avatar,
) -> dict:
    """Validate the clips, write the study folder; returns a summary (counts and balance)."""
    from facecapges.study.clips import load_clips

    out = Path(out)
    _check_study_out(out, force, n_participants)

    cs, motions, faces = load_clips(clips_yaml)

    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import write_glb
    from facecapges.progress import Progress

    plan = make_plan(cs.clip_ids, cs.systems, n_participants, seed)
    for p in plan.participants:
        p.token = new_token()
    skel = motions[cs.clips[0].id][cs.systems[0]].skeleton
    joint_names = list(skel.names)
    driver = None
    if avatar is not None:
        from facecapges.avatar.vrm.view import VrmDriver

        driver = VrmDriver.from_file(avatar, skel)
    if (out / STUDY_FILE).exists() and (out / "media").is_dir():  # an old study's media (--force)
        shutil.rmtree(out / "media")
    out.mkdir(parents=True, exist_ok=True)
    clips_meta = []
    with Progress(disable=not progress, transient=True) as bar:
        task = bar.add_task("preparing clips", total=len(cs.clips) * (len(cs.systems) + 1) + 1)
        if driver is None:
            write_glb(default_avatar(skel), out / AVATAR_FILE)
        else:
            (out / VRM_FILE).write_bytes(driver.model.data)
        bar.advance(task)
        for clip in cs.clips:
            clips_meta.append(_write_clip(out, clip, cs, motions, faces, driver, joint_names, bar, task))
    doc = _study_doc(clips_yaml, cs, driver is None, clips_meta, plan)
    (out / "responses").mkdir(exist_ok=True)
    write_private(out / STUDY_FILE, json.dumps(doc, indent=1) + "\n")
    write_invitations(out, plan)
    return {
        "clips": len(cs.clips),
        "systems": len(cs.systems),
        "participants": len(plan.participants),
        "fps": cs.fps,
        "balance": doc["balance"],
    }


def _study_doc(clips_yaml: str | Path, cs, our_avatar: bool, clips_meta: list[dict], plan: StudyPlan) -> dict:
    """The study file's content: source, rate, systems, avatar, clips, criteria, the plan and its balance."""
    doc = {
        "format": FORMAT,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "source": str(Path(clips_yaml)),
        "fps": cs.fps,
        "systems": cs.systems,
        "avatar": AVATAR_FILE if our_avatar else VRM_FILE,
        "clips": clips_meta,
        "criteria": [c.to_json() for c in CRITERIA],
        "balance": balance_report(plan),
        "plan": plan.to_json(),
    }
    return doc


def _check_study_out(out: Path, force: bool, n_participants: int | None) -> None:
    """Refuse an output that is a file, holds answers, or (without ``force``) a study or other files."""
    if out.exists() and not out.is_dir():
        raise file_error(out, "exists and is not a folder")
    if (out / STUDY_FILE).exists():
        answered = sorted((out / "responses").glob("*.json")) if (out / "responses").is_dir() else []
        if answered:
            raise file_error(
                out,
                f"holds the answers of {len(answered)} participant(s) in responses/; move them "
                "away before re-creating this study",
            )
        if not force:
            raise file_error(out / STUDY_FILE, "already exists; pass --force to overwrite the study")
    elif out.exists() and any(out.iterdir()) and not force:
        raise file_error(out, "is a non-empty folder; pass --force to write the study into it")
    if n_participants is not None and n_participants < 1:
        raise UserError(f"--participants must be at least 1, got {n_participants}")


def _write_clip(out: Path, clip, cs, motions: dict, faces: dict, driver, joint_names: list[str], bar, task) -> dict:
    """Write one clip's media (audio, face, one motion per system) at the study's rate; its entry in the study."""
    from facecapges.avatar.render.video import bvh_quaternions
    from facecapges.io.audio import save_audio
    from facecapges.timing import resample

    n = int(round(clip.duration * cs.fps))
    d = media_dir(out, clip.id)
    d.mkdir(parents=True, exist_ok=True)
    save_audio(d / "audio.wav", clip.audio)
    _write_face(d, faces[clip.id], cs.fps, n, driver)
    bar.advance(task)
    for s in cs.systems:
        b = motions[clip.id][s]
        q = bvh_quaternions(joint_names, b.skeleton, b.motion, f"clip {clip.id!r}, system {s!r}")
        q = _fit(resample(q, b.fps, cs.fps), n)
        doc = {"fps": cs.fps, "frames": n, "joint_names": joint_names}
        if driver is not None:
            from facecapges.rotations import quaternion_to_matrix

            q = driver.retarget(quaternion_to_matrix(q))
            doc = {"fps": cs.fps, "frames": n, "bone_names": list(driver.retarget.bones)}
        motion_file(out, clip.id, s).write_text(json.dumps({**doc, "quats": _numbers(q)}), "utf-8")
        bar.advance(task)
    return {
        "id": clip.id,
        "frames": n,
        "duration": clip.duration,
        "audio_source": str(clip.audio_path),
        "face_source": str(clip.face_path) if clip.face_path else None,
        "bvh_sources": {s: str(p) for s, p in clip.bvh_paths.items()},
    }


def _write_face(d: Path, tr, fps: float, n: int, driver) -> None:
    """A clip's face track (ARKit, or the VRM's expressions with ``driver``) resampled to ``n`` frames at ``fps``."""
    from facecapges.arkit import ARKIT_NAMES
    from facecapges.timing import resample

    w = np.zeros((n, len(ARKIT_NAMES)), np.float32)
    if tr is not None:
        w = _fit(resample(tr.weights, tr.fps, fps), n)
    names = list(ARKIT_NAMES)
    if driver is not None:
        w, names = driver.faces(w), list(driver.faces.names)
    (d / "face.json").write_text(
        json.dumps({"fps": fps, "frames": n, "names": names, "weights": _numbers(np.clip(w, 0.0, 1.0), 3)}),
        "utf-8",
    )


@dataclass
class Study:
    """An opened study folder."""

    dir: Path
    doc: dict
    plan: StudyPlan

    @property
    def systems(self) -> list[str]:
        return list(self.doc["systems"])

    @property
    def clips(self) -> dict[str, dict]:
        return {c["id"]: c for c in self.doc["clips"]}

    @property
    def responses_dir(self) -> Path:
        return self.dir / "responses"


def open_study(study_dir: str | Path) -> Study:
    """Read ``STUDY_DIR/study.json`` (UserError when it is missing or not a study)."""
    d = Path(study_dir)
    f = d / STUDY_FILE
    if not f.is_file():
        raise file_error(d, f"not a study folder (no {STUDY_FILE}); make one with 'facecapges study create'")
    try:
        doc = json.loads(f.read_text(encoding="utf-8"))
        if not isinstance(doc, dict):
            raise ValueError("not a JSON object")
        if doc.get("format") != FORMAT:
            raise ValueError(f"format is {str(doc.get('format'))[:40]!r}, expected {FORMAT!r}")
        plan = StudyPlan.from_json(doc["plan"])
    except RecursionError:
        raise file_error(f, "not a valid study file (nested too deeply)") from None
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
        raise file_error(f, f"not a valid study file ({exc.__class__.__name__}: {str(exc)[:100]})") from None
    return Study(d, doc, plan)
