"""MediaPipe's pose and hand landmarker bundles, built at set-up from a PyPI wheel.

The Tasks API of the ``mediapipe`` we pin (1.2.2) loads ``.task`` bundles, and no
wheel on PyPI ships ``pose_landmarker*.task`` / ``hand_landmarker.task``. The
TFLite models inside them do ship in the ``mediapipe==0.10.14`` wheel (the legacy
"Solutions" graphs): BlazePose ``pose_detection.tflite`` + ``pose_landmark_full.tflite``
and the hand models ``palm_detection_full.tflite`` + ``hand_landmark_full.tflite``.
``scripts/setup-capture.sh`` fetches that wheel with ``pip download --no-deps`` (its
sha256 pinned below), and :func:`build_bundles` turns the four models into two
bundles under :func:`models_dir` (inside the virtualenv):

- ``hand_landmarker.task``: ``hand_detector.tflite`` + ``hand_landmarks_detector.tflite``,
  stored uncompressed; the HandLandmarker takes them as they are.
- ``pose_landmarker_full.task``: ``pose_detector.tflite`` + ``pose_landmarks_detector.tflite``.
  The PoseLandmarker refuses models without TFLite metadata saying how their
  input is normalised, so both get that metadata (image input, RGB; the detector
  mean 127.5 / std 127.5, i.e. pixels to [-1, 1], the landmark model mean 0 / std
  255, i.e. [0, 1], as BlazePose's own graphs feed them) written with mediapipe's
  own metadata writer.

Every input model and both bundles are checked against the sha256 values here, so
a different wheel or writer fails the set-up loudly. The models are Google's,
under Apache-2.0 (the wheel's LICENSE; the BlazePose and hand model cards).
Nothing is downloaded at run time.
"""

from __future__ import annotations

import hashlib
import os
import sys
import types
import zipfile
from pathlib import Path

from facecapges.errors import UserError

WHEEL_VERSION = "0.10.14"
WHEEL_NAME = "mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
WHEEL_SHA256 = "a807328339e7356fda0bb14df12fedbf1d33bdf81649c5f8666b0026b1cc30b4"

# wheel member -> (name inside the bundle, sha256 of the wheel's file)
POSE_MEMBERS = {
    "mediapipe/modules/pose_detection/pose_detection.tflite": "pose_detector.tflite",
    "mediapipe/modules/pose_landmark/pose_landmark_full.tflite": "pose_landmarks_detector.tflite",
}
HAND_MEMBERS = {
    "mediapipe/modules/palm_detection/palm_detection_full.tflite": "hand_detector.tflite",
    "mediapipe/modules/hand_landmark/hand_landmark_full.tflite": "hand_landmarks_detector.tflite",
}
POSE_TASK = "pose_landmarker_full.task"
HAND_TASK = "hand_landmarker.task"
BUNDLE_SHA256 = {
    POSE_TASK: "182855c69ea32604a6b492704bf025b0c123366eb46775b78942582e9c70673e",
    HAND_TASK: "b0235e7de18c847c1aa5bfc67083085a1c6374ef97a2c8ad04c58ce9c3faf2fe",
}
SETUP_HINT = "run scripts/setup-capture.sh (or make setup): it builds the pose and hand models from mediapipe==0.10.14"

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
_ALIGN = 4


def models_dir() -> Path:
    """Where the built bundles live: ``<venv>/share/facecapges/mediapipe-0.10.14``
    (or ``$FACECAPGES_BODY_MODELS`` when set)."""
    env = os.environ.get("FACECAPGES_BODY_MODELS")
    if env:
        return Path(env)
    return Path(sys.prefix) / "share" / "facecapges" / f"mediapipe-{WHEEL_VERSION}"


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _metadata_writer() -> types.ModuleType:
    """mediapipe's TFLite metadata writer.

    mediapipe 1.2.2's wheel lacks the small native module the writer imports only
    to compute the metadata's ``min_parser_version``; it is given here as "1.0.0",
    the schema version that introduced image NormalizationOptions (all we write).
    """
    name = "mediapipe.tasks.cc.metadata.python._pywrap_metadata_version"
    if name not in sys.modules:
        try:
            __import__(name)
        except ImportError:
            parts = name.split(".")
            for i in range(3, len(parts)):
                pkg = ".".join(parts[:i])
                sys.modules.setdefault(pkg, types.ModuleType(pkg))
            mod = types.SimpleNamespace(GetMinimumMetadataParserVersion=lambda _buf: "1.0.0")
            sys.modules[name] = mod  # type: ignore[assignment]
            setattr(sys.modules[".".join(parts[:-1])], parts[-1], mod)
    from mediapipe.tasks.python.metadata.metadata_writers import metadata_writer

    return metadata_writer


def _with_normalization(model: bytes, name: str, mean: float, std: float) -> bytes:
    """``model`` with TFLite metadata: an RGB image input normalised as (pixel - mean) / std."""
    mw = _metadata_writer()
    from mediapipe.tasks.python.metadata.metadata_writers import writer_utils

    writer = mw.MetadataWriter.create(bytearray(model))
    writer.add_general_info(name, f"{name} from mediapipe {WHEEL_VERSION}, input (pixel - {mean:g}) / {std:g}")
    writer.add_image_input(norm_mean=[mean], norm_std=[std])
    for _ in writer_utils.get_output_tensor_names(bytearray(model)):
        writer.add_feature_output()
    out, _json = writer.populate()
    return bytes(out)


def _write_bundle(path: Path, members: dict[str, bytes]) -> None:
    """An uncompressed zip, each member's data 4-byte aligned, fixed dates (reproducible)."""
    from mediapipe.tasks.python.metadata.metadata_writers.model_asset_bundle_utils import AlignZipFile

    tmp = path.with_suffix(".part")
    with AlignZipFile(tmp, "w", alignment=_ALIGN) as z:
        for name, data in members.items():
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
    tmp.replace(path)


def build_bundles(wheel: str | Path, out_dir: str | Path | None = None) -> dict[str, Path]:
    """Build both bundles from the mediapipe 0.10.14 wheel; verify every hash."""
    wheel = Path(wheel)
    got = hashlib.sha256(wheel.read_bytes()).hexdigest()
    if got != WHEEL_SHA256:
        raise UserError(f"{wheel}: sha256 {got}, expected {WHEEL_SHA256} (mediapipe {WHEEL_VERSION} wheel)")
    out = Path(out_dir) if out_dir is not None else models_dir()
    out.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as z:
        pose = {POSE_MEMBERS[m]: z.read(m) for m in POSE_MEMBERS}
        hand = {HAND_MEMBERS[m]: z.read(m) for m in HAND_MEMBERS}
    # BlazePose's own graphs feed the detector pixels in [-1, 1] and the landmark model [0, 1]
    pose["pose_detector.tflite"] = _with_normalization(pose["pose_detector.tflite"], "pose_detector", 127.5, 127.5)
    pose["pose_landmarks_detector.tflite"] = _with_normalization(
        pose["pose_landmarks_detector.tflite"], "pose_landmarks_detector", 0.0, 255.0
    )
    paths = {POSE_TASK: out / POSE_TASK, HAND_TASK: out / HAND_TASK}
    _write_bundle(paths[POSE_TASK], pose)
    _write_bundle(paths[HAND_TASK], hand)
    for name, p in paths.items():
        digest = sha256_bytes(p.read_bytes())
        want = BUNDLE_SHA256.get(name)
        if want and digest != want:
            raise UserError(f"{p}: sha256 {digest}, expected {want}")
    return paths


def model_path(name: str) -> Path:
    """The verified bundle ``name`` (POSE_TASK or HAND_TASK), or a UserError saying how to get it."""
    p = models_dir() / name
    if not p.is_file():
        raise UserError(f"the body-capture model {name} is not installed; {SETUP_HINT}")
    want = BUNDLE_SHA256.get(name)
    if want:
        digest = sha256_bytes(p.read_bytes())
        if digest != want:
            raise UserError(f"{p}: sha256 {digest}, expected {want}; {SETUP_HINT}")
    return p


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m facecapges.capture.body_models MEDIAPIPE_0.10.14_WHEEL", file=sys.stderr)
        return 2
    try:
        paths = build_bundles(args[0])
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for p in paths.values():
        print(f"{p} sha256 {sha256_bytes(p.read_bytes())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
