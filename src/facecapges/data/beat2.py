"""BEAT2 (SMPL-X) takes → the BEAT upper-body pose and a jawOpen face track.

BEAT2 (Liu et al., EMAGE, CVPR 2024) re-released BEAT's optical mocap fitted to SMPL-X.
A take is ``smplxflame_30/{speaker}_{name}_{type}_{start}_{end}.npz`` beside its speech
``wave16k/<same name>.wav``; the npz holds ``poses`` (T, 165) = 55 SMPL-X joints ×
axis-angle (radians, local to the parent, SMPL-X joint order) and ``mocap_frame_rate``
(30), plus ``trans``, ``expressions`` (FLAME) and ``betas``, which are not used here.

**Conversion** (every matrix acts on column vectors):

1. SMPL-X local matrices ``R_s`` from the axis-angles; global ones ``S_s`` by the parent
   chain (SMPL-X's rest pose has every joint frame aligned with the world, so no SMPL-X
   model file is needed).
2. Each BEAT joint j with a SMPL-X counterpart s(j) gets the SMPL-X rotation relative to
   the counterpart a of its nearest BEAT ancestor that has one: ``M_j = S_a⁻¹ S_s(j)``
   (for all but the fingers this is SMPL-X's own local rotation; a finger's first
   joint is taken against the wrist, past BEAT's metacarpal joints).
3. ``L_j = A_j · M_j · B_j``: two constant rotations per joint (:data:`MAP_NAME`),
   fitted by least squares on SO(3) on the calibration pair (:func:`fit_map`). With
   both rest poses world-aligned, ``B_j`` is the BEAT joint's rest frame seen from the
   SMPL-X joint's, and ``A_j`` the same for the parent (it also absorbs the constant
   rotation of a BEAT joint SMPL-X lacks between them).
4. **Twist and flexion lines**: BEAT's skeleton solver and the SMPL-X fit share the twist along
   each arm differently (BEAT keeps the wrist's twist in the forearm), and SMPL-X's fingers bend
   about twice as far as BEAT's. For the upper arm, forearm and hand of each side the rotation
   about the bone (x) is followed by ``Rx(c · [τ_arm, τ_forearm, τ_hand, 1])``, a least-squares
   line of the chain's twists; each index/middle/ring/little finger joint likewise gets
   ``Rz(c · [φ, 1])`` of its own flexion φ (:data:`TWIST_CHAINS`, :func:`fit_twist`).
5. **Finger amplitudes**: BEAT's skeleton solver keeps the fingers' second and third joints as hinges
   (they turn about z only, x and y still) and its thumbs move 2–5× less than the SMPL-X (MANO) fit's,
   whose finger joints also jitter about every axis (on the calibration pair the converted thumbs
   accelerated 2.5× as hard as BEAT's own mocap of the same frames at the 99th percentile, and
   0_2_2's left thumb tip swings 95° in two 30 fps frames). Each finger joint's rotation about a
   constant centre ``c_j`` (its mean over the fitting frames) is scaled per axis,
   ``L_j ← c_j · exp(g_j ⊙ log(c_j⁻¹ L_j))``, with gains ``g_j`` (3,) fitted by least squares on the
   pair (:data:`GAIN_JOINTS`, :func:`fit_gains`; g ≈ 0 about a hinge's still axes).
6. BEAT joints SMPL-X lacks — the metacarpals ``*HandIndex``, ``*HandRing``,
   ``*HandPinky`` and ``Neck1`` — hold a constant: their mean rotation in the BEAT
   take (they move by 1–2° there). BEAT's ``Spine`` is driven by SMPL-X ``spine1``
   relative to the pelvis, ``Neck`` by ``neck`` relative to ``spine3`` (BEAT's data
   keeps Hips, Spine1–3 and Head at rest, as here).

Steps 1–5 are :func:`convert_matrices`. The choice of what drives Spine and Neck1 was made on a validation part of the pair
(``docs/bring-your-own-mocap.md`` has the figures).

**Time.** A take is resampled to the model rate by :func:`facecapges.timing.resample`
(30 → 15 fps keeps every other frame, frame i at time i/15), keeping BEAT2's own
alignment with its wav: the jaw follows the wav's loudness at lag 0. The shared BEAT
BVH of the same take is one 30 fps frame earlier (its frame i is npz frame 2i − 1,
:func:`measure_lag`); the pair is aligned by that lag only for fitting and checking.

**Face.** BEAT2's jaw joint opens about the x axis (a few degrees in these takes).
``jawOpen = clip(jaw_offset + jaw_scale · θx, 0, 1)``: a linear map whose mean and
spread over the fitting frames equal BEAT's own ARKit jawOpen statistics (the
4-speaker mean 0.176, std 0.095 of BEAT's face capture), so a converted take's jaw
looks to the model like the jawOpen of a BEAT face capture or of the live camera.
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES, arkit_index
from facecapges.data.beat import check_skeleton
from facecapges.errors import UserError, file_error
from facecapges.skeleton import N_JOINTS, UPPER_BODY

MOTION_DIR = "smplxflame_30"  # BEAT2's folder of SMPL-X takes
AUDIO_DIR = "wave16k"  # … and of their 16 kHz speech
MAP_NAME = "beat2"  # data/maps/beat2.json: the fitted corrections
MAX_FPS = 1000.0
#: Caps on what a take may cost (docs/bring-your-own-mocap.md): each array's uncompressed size (checked on
#: the zip member and on its npy header before it is unpacked), the take's length, and its frame count.
MAX_MEMBER_BYTES = 96 << 20  # 72,000 frames of float64 poses: 95 MB
MAX_TAKE_S = 20 * 60.0
MAX_FRAMES = 72_000  # 20 min at 60 fps (BEAT2 is 30)
#: Axis-angle magnitudes above this are refused (a fit gives at most π; BEAT2's own reach 2.45 rad).
MAX_ANGLE = 4 * np.pi
#: A take shorter than this is warned about (``styles build`` refuses it: its first 80 % must hold 10 s).
MIN_USEFUL_S = 12.5

SMPLX_NAMES: tuple[str, ...] = (
    ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle")
    + ("right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head")
    + ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw")
    + ("left_eye", "right_eye")
    + tuple(
        f"{side}_{finger}{k}"
        for side in ("left", "right")
        for finger in ("index", "middle", "pinky", "ring", "thumb")
        for k in (1, 2, 3)
    )
)
SMPLX_PARENTS: tuple[int, ...] = (
    (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15)
    + tuple(p for f in range(5) for p in (20, 25 + 3 * f, 26 + 3 * f))
    + tuple(p for f in range(5) for p in (21, 40 + 3 * f, 41 + 3 * f))
)
N_SMPLX = len(SMPLX_NAMES)  # 55
JAW = SMPLX_NAMES.index("jaw")
assert N_SMPLX == 55 and len(SMPLX_PARENTS) == 55


def _arm_sources(side: str) -> dict[str, tuple[str, str] | None]:
    s, B = side.lower(), side
    out: dict[str, tuple[str, str] | None] = {
        f"{B}Shoulder": (f"{s}_collar", "spine3"),
        f"{B}Arm": (f"{s}_shoulder", f"{s}_collar"),
        f"{B}ForeArm": (f"{s}_elbow", f"{s}_shoulder"),
        f"{B}Hand": (f"{s}_wrist", f"{s}_elbow"),
    }
    for finger in ("Middle", "Ring", "Pinky", "Index", "Thumb"):
        f = finger.lower()
        if finger != "Middle" and finger != "Thumb":
            out[f"{B}Hand{finger}"] = None  # BEAT's metacarpal joint: SMPL-X has none
        for k in (1, 2, 3):
            out[f"{B}Hand{finger}{k}"] = (f"{s}_{f}{k}", f"{s}_wrist" if k == 1 else f"{s}_{f}{k - 1}")
    return out


#: BEAT joint → (SMPL-X joint, SMPL-X joint it is taken relative to), or None: a constant.
SOURCES: dict[str, tuple[str, str] | None] = {
    "Spine": ("spine1", "pelvis"),
    "Neck": ("neck", "spine3"),
    "Neck1": None,
    **_arm_sources("Right"),
    **_arm_sources("Left"),
}
assert set(SOURCES) == set(UPPER_BODY)

#: (axis, joints): the arm chains whose twist about the bone (x, along BEAT's arms) is redistributed,
#: and the finger joints whose flexion (about z) is rescaled (module docstring, step 4).
TWIST_CHAINS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("X", ("RightArm", "RightForeArm", "RightHand")),
    ("X", ("LeftArm", "LeftForeArm", "LeftHand")),
) + tuple(
    ("Z", (f"{side}Hand{finger}{k}",))
    for side in ("Right", "Left")
    for finger in ("Middle", "Ring", "Pinky", "Index")
    for k in (1, 2, 3)
)
_TWIST_WIDTH = {j: len(chain) + 1 for _, chain in TWIST_CHAINS for j in chain}  # coefficients of a joint's line

#: The finger joints whose amplitude about their centre is rescaled per axis (module docstring, step 5).
GAIN_JOINTS: tuple[str, ...] = tuple(n for n in UPPER_BODY if "Hand" in n and n[-1] in "123" and SOURCES[n] is not None)
MAX_GAIN = 1.5


# ------------------------------------------------------------------ reading
@dataclass
class Beat2Take:
    """One BEAT2 take as read: ``poses`` (T, 55, 3) axis-angle radians, float64."""

    path: Path
    poses: np.ndarray
    fps: float
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return len(self.poses)


def _npy_header(f, key: str, path: Path) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from a member's npy header (numpy's own reader; nothing of the data read yet)."""
    from numpy.lib import format as npy

    version = npy.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = npy.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, _, dtype = npy.read_array_header_2_0(f)
    else:
        raise ValueError(f"npy format version {version[0]}.{version[1]} (1.0 or 2.0 expected)")
    if dtype.hasobject:
        raise file_error(path, f"not a BEAT2 take: {key!r} holds Python objects (refused: no pickle)")
    return tuple(int(d) for d in shape), dtype


def _member(z: zipfile.ZipFile, key: str, path: Path, fps: float = 1.0) -> np.ndarray:
    """One ``key.npy`` of the archive, its size checked before anything is unpacked (module constants):
    the member's declared uncompressed size, then its npy header's shape and dtype."""
    from numpy.lib import format as npy

    info = z.getinfo(f"{key}.npy")
    if info.file_size > MAX_MEMBER_BYTES:
        raise file_error(
            path,
            f"{key!r} unpacks to {info.file_size / 2**20:.0f} MB, more than the {MAX_MEMBER_BYTES >> 20} MB "
            "a BEAT2 take's array may be (docs/bring-your-own-mocap.md)",
        )
    with z.open(info) as f:
        try:
            shape, dtype = _npy_header(f, key, path)
        except (ValueError, SyntaxError, TypeError) as exc:  # numpy's header errors
            raise file_error(path, f"not a BEAT2 take: {key!r} has no valid npy header ({str(exc)[:120]})") from None
        if key == "poses" and shape and shape[0] > min(MAX_FRAMES, MAX_TAKE_S * fps):
            raise file_error(
                path,
                f"{shape[0]} frames at {fps:g} fps ({shape[0] / fps / 60:.1f} min): longer than a BEAT2 take may be "
                f"({MAX_TAKE_S / 60:g} min, at most {MAX_FRAMES} frames; docs/bring-your-own-mocap.md)",
            )
        nbytes = dtype.itemsize * math.prod(shape)
        if nbytes > info.file_size:
            raise file_error(
                path, f"damaged BEAT2 take: {key!r} declares shape {shape} ({nbytes} bytes) in {info.file_size} bytes"
            )
        f.seek(0)
        return npy.read_array(f, allow_pickle=False)


def _check_float(a: np.ndarray, key: str, shape: tuple, path: Path) -> np.ndarray:
    want = "(" + ", ".join("T" if d is None else str(d) for d in shape) + ")"
    if a.ndim != len(shape) or any(d is not None and a.shape[i] != d for i, d in enumerate(shape)):
        raise file_error(path, f"not a BEAT2 take: {key!r} has shape {a.shape}, expected {want}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise file_error(path, f"not a BEAT2 take: {key!r} has dtype {a.dtype}, expected floats")
    with np.errstate(over="ignore"):
        a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise file_error(path, f"damaged BEAT2 take: {key!r} has NaN or infinite values")
    return a


def _frame_rate(a: np.ndarray, path: Path) -> float:
    if a.size != 1 or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise file_error(path, f"not a BEAT2 take: 'mocap_frame_rate' must be one number, got {a.dtype} {a.shape}")
    fps = float(a.reshape(()))
    if not np.isfinite(fps) or not 1.0 <= fps <= MAX_FPS:
        raise file_error(path, f"not a BEAT2 take: frame rate {fps} is not 1–{MAX_FPS:g} fps")
    return fps


def _check_angles(poses: np.ndarray, path: Path) -> None:
    """Axis-angle rotations beyond :data:`MAX_ANGLE` are not a fit's output: refused, not wrapped."""
    with np.errstate(over="ignore", invalid="ignore"):  # 1e300 squared: inf, refused below
        angle = np.linalg.norm(poses.reshape(len(poses), N_SMPLX, 3), axis=-1)
    bad = np.argwhere(angle > MAX_ANGLE)
    if len(bad):
        t, j = (int(v) for v in bad[0])
        raise file_error(
            path,
            f"damaged BEAT2 take: {len(bad)} rotation(s) beyond {MAX_ANGLE / np.pi:g}π rad, first at frame {t}, "
            f"joint {SMPLX_NAMES[j]} ({angle[t, j]:.3g} rad)",
        )


def read_beat2(path: str | Path) -> Beat2Take:
    """Read a BEAT2 SMPL-X ``.npz`` (no pickle). Anything wrong is one UserError naming the file.

    Each array's declared size (the zip member's and its npy header's) is checked before it is unpacked:
    :data:`MAX_MEMBER_BYTES`, :data:`MAX_TAKE_S`; rotations beyond :data:`MAX_ANGLE` are refused.
    """
    path = Path(path)
    if not path.is_file():
        raise file_error(path, "BEAT2 take not found")
    with path.open("rb") as f:
        if f.read(6) == b"\x93NUMPY":
            raise file_error(path, "not a BEAT2 take (a single .npy array, not an .npz archive)")
    try:
        z = zipfile.ZipFile(path)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        raise file_error(path, "not a BEAT2 take: not a readable .npz archive (damaged or another format)") from None
    try:
        with z:
            files = {n[: -len(".npy")] for n in z.namelist() if n.endswith(".npy")}
            missing = [k for k in ("poses", "mocap_frame_rate") if k not in files]
            if missing:
                raise file_error(path, f"not a BEAT2 take: no {', '.join(repr(k) for k in missing)} array")
            fps = _frame_rate(_member(z, "mocap_frame_rate", path), path)
            raw = {k: _member(z, k, path, fps) for k in ("poses", "trans") if k in files}
    except UserError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, NotImplementedError, zlib.error) as exc:
        raise file_error(path, f"unreadable BEAT2 take ({exc.__class__.__name__}: {str(exc)[:120]})") from None
    poses = _check_float(raw["poses"], "poses", (None, N_SMPLX * 3), path)
    if len(poses) < 2:
        raise file_error(path, f"BEAT2 take has {len(poses)} frame(s); a take needs at least 2")
    _check_angles(poses, path)
    extras = {}
    if "trans" in raw:
        extras["trans"] = _check_float(raw["trans"], "trans", (len(poses), 3), path)
    return Beat2Take(path=path, poses=poses.reshape(-1, N_SMPLX, 3), fps=fps, extras=extras)


# ------------------------------------------------------------------ rotations
def smplx_globals(poses: np.ndarray) -> np.ndarray:
    """Global rotations (T, 55, 3, 3) of SMPL-X axis-angle poses (T, 55, 3) (world-aligned rest)."""
    local = rot.exp_so3(poses)
    G = np.empty_like(local)
    for j, p in enumerate(SMPLX_PARENTS):
        G[:, j] = local[:, j] if p < 0 else G[:, p] @ local[:, j]
    return G


def source_rotations(poses: np.ndarray) -> np.ndarray:
    """``M_j`` (T, 47, 3, 3) of every BEAT joint (module docstring, step 2); identity for constants."""
    G = smplx_globals(poses)
    M = np.broadcast_to(np.eye(3), (len(poses), N_JOINTS, 3, 3)).copy()
    for i, name in enumerate(UPPER_BODY):
        src = SOURCES[name]
        if src is not None:
            j, a = SMPLX_NAMES.index(src[0]), SMPLX_NAMES.index(src[1])
            M[:, i] = np.swapaxes(G[:, a], -1, -2) @ G[:, j]
    return M


# ------------------------------------------------------------------ the map
@dataclass
class Beat2Map:
    """Fitted constants: ``left``/``right`` (47, 3, 3) per joint, the jaw → jawOpen line, provenance."""

    left: np.ndarray
    right: np.ndarray
    jaw_offset: float
    jaw_scale: float
    twist: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    gains: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # joint → (centre (3, 3), g (3,))

    def to_dict(self) -> dict:
        q = {n: {"left": _q(self.left[i]), "right": _q(self.right[i])} for i, n in enumerate(UPPER_BODY)}
        tw = {n: [round(float(v), 6) for v in c] for n, c in self.twist.items()}
        jaw = {"offset": self.jaw_offset, "scale_per_rad": self.jaw_scale}
        gains = {n: {"centre": _q(c), "gain": [round(float(v), 6) for v in g]} for n, (c, g) in self.gains.items()}
        return {**self.info, "jaw": jaw, "twist": tw, "gains": gains, "joints": q}

    @classmethod
    def from_dict(cls, d: dict, origin: str) -> Beat2Map:
        try:
            left = np.stack([rot.quaternion_to_matrix(_unit(d["joints"][n]["left"])) for n in UPPER_BODY])
            right = np.stack([rot.quaternion_to_matrix(_unit(d["joints"][n]["right"])) for n in UPPER_BODY])
            off, scale = float(d["jaw"]["offset"]), float(d["jaw"]["scale_per_rad"])
            twist = {str(n): np.asarray(c, np.float64) for n, c in d.get("twist", {}).items()}
            for n, c in twist.items():
                width = _TWIST_WIDTH.get(n)
                if width is None or c.shape != (width,) or not np.isfinite(c).all():
                    raise ValueError(f"twist of {n!r}: not a joint of TWIST_CHAINS or not {width} numbers")
            gains = {}
            for n, e in d.get("gains", {}).items():
                g = np.asarray(e["gain"], np.float64)
                if n not in GAIN_JOINTS or g.shape != (3,) or not np.isfinite(g).all():
                    raise ValueError(f"gains of {n!r}: not a joint of GAIN_JOINTS or not 3 numbers")
                gains[str(n)] = (rot.quaternion_to_matrix(_unit(e["centre"])), g)
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"{origin}: not a BEAT2 correction map ({exc.__class__.__name__}: {exc})") from None
        if not (np.isfinite(off) and np.isfinite(scale)):
            raise UserError(f"{origin}: not a BEAT2 correction map (jaw line not finite)")
        info = {k: v for k, v in d.items() if k not in ("jaw", "joints", "twist", "gains")}
        return cls(left, right, off, scale, twist, info, gains)


def _q(m: np.ndarray) -> list[float]:
    return [round(float(v), 7) for v in rot.matrix_to_quaternion(m)]


def _unit(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-6:
        raise ValueError(f"{q.tolist()} is not a quaternion [w, x, y, z]")
    return q / np.linalg.norm(q)


def map_path() -> Path:
    """The shipped correction map, ``facecapges/data/maps/beat2.json``."""
    return Path(str(resources.files("facecapges.data") / "maps" / f"{MAP_NAME}.json"))


def load_map(path: str | Path | None = None) -> Beat2Map:
    """The correction map at ``path`` (default: the shipped one)."""
    p = map_path() if path is None else Path(path)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise file_error(p, "BEAT2 correction map not found") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise file_error(p, f"malformed BEAT2 correction map ({exc})") from None
    if not isinstance(d, dict):
        raise file_error(p, "a BEAT2 correction map is a JSON object")
    return Beat2Map.from_dict(d, str(p))


# ------------------------------------------------------------------ conversion
def convert_matrices(take: Beat2Take, mapping: Beat2Map | None = None) -> np.ndarray:
    """BEAT local rotations (T, 47, 3, 3) of a take, at its own frame rate."""
    m = mapping or load_map()
    return corrected(source_rotations(take.poses), m)


def corrected(M: np.ndarray, m: Beat2Map) -> np.ndarray:
    """Steps 3–5 of the module docstring on source rotations ``M`` (T, 47, 3, 3): BEAT local rotations."""
    return finger_amplitudes(redistribute_twist(m.left[None] @ M @ m.right[None], m.twist), m.gains)


def finger_amplitudes(P: np.ndarray, gains: dict[str, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """``L_j = c_j · exp(g_j ⊙ log(c_j⁻¹ P_j))`` for the joints in ``gains`` (module docstring, step 5)."""
    out = P.copy()
    for n, (c, g) in gains.items():
        i = UPPER_BODY.index(n)
        rv = rot.log_so3(c.T[None] @ P[:, i]) * g
        out[:, i] = c[None] @ rot.exp_so3(rv)
    return out


def fit_gains(P: np.ndarray, L: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per joint of :data:`GAIN_JOINTS`: its centre (the mean of ``P``) and the per-axis least-squares gain
    from ``P``'s rotation vector about it to ``L``'s about ``L``'s mean, in [0, :data:`MAX_GAIN`]."""
    out = {}
    for n in GAIN_JOINTS:
        i = UPPER_BODY.index(n)
        c = rot.mean_rotation_matrix(P[:, i])
        x = rot.log_so3(c.T[None] @ P[:, i])
        y = rot.log_so3(rot.mean_rotation_matrix(L[:, i]).T[None] @ L[:, i])
        x, y = x - x.mean(0), y - y.mean(0)
        g = np.clip((x * y).sum(0) / np.maximum((x * x).sum(0), 1e-12), 0.0, MAX_GAIN)
        out[n] = (c, g)
    return out


def twist_features(P: np.ndarray, axis: str, chain: tuple[str, ...]) -> np.ndarray:
    """(T, len(chain) + 1): the chain's twists about ``axis`` and a 1 column."""
    tw = rot.twist_angle(P[:, [UPPER_BODY.index(n) for n in chain]], axis)
    return np.concatenate([tw, np.ones((len(P), 1))], axis=1)


def redistribute_twist(P: np.ndarray, twist: dict[str, np.ndarray]) -> np.ndarray:
    """``L_j = P_j · R_axis(features · c_j)`` for the joints of :data:`TWIST_CHAINS` in ``twist``."""
    out = P.copy()
    for axis, chain in TWIST_CHAINS:
        X = twist_features(P, axis, chain)
        for n in chain:
            if n in twist:
                i = UPPER_BODY.index(n)
                out[:, i] = P[:, i] @ rot.axis_angle_matrix(axis, X @ twist[n])
    return out


def jaw_open(take: Beat2Take, mapping: Beat2Map | None = None) -> np.ndarray:
    """jawOpen (T,) in 0..1 from the jaw's opening angle (rotation about x, radians)."""
    m = mapping or load_map()
    return np.clip(m.jaw_offset + m.jaw_scale * take.poses[:, JAW, 0], 0.0, 1.0)


def face_track(jaw: np.ndarray) -> np.ndarray:
    """A (T, 52) ARKit face array with only jawOpen filled."""
    face = np.zeros((len(jaw), N_BLENDSHAPES), np.float32)
    idx = arkit_index("jawOpen")
    assert idx is not None
    face[:, idx] = jaw
    return face


def convert_take(
    take: Beat2Take, fps: float = timing.MODEL_FPS, mapping: Beat2Map | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(pose (T, 47, 6) rot6d float32, face (T, 52) float32 with jawOpen) at ``fps``."""
    m = mapping or load_map()
    idx = timing.resample_indices(take.n_frames, take.fps, fps)
    sub = Beat2Take(take.path, take.poses[idx], fps)
    pose = rot.matrix_to_rot6d(convert_matrices(sub, m)).astype(np.float32)
    face = face_track(jaw_open(sub, m))
    if not (np.isfinite(pose).all() and np.isfinite(face).all()):
        raise file_error(take.path, "BEAT2 take converts to NaN or infinite poses (damaged values)")
    return pose, face


def load_beat2_take(npz_path: str | Path, fps: float = timing.MODEL_FPS) -> tuple[np.ndarray, np.ndarray]:
    """A BEAT2 take converted: pose (T, 47, 6) rot6d float32 (UPPER_BODY order, local
    rotations) and face (T, 52) float32 (ARKit order, only jawOpen non-zero), at ``fps``.

    Its speech: :func:`beat2_wav` and :func:`facecapges.io.audio.load_audio` (16 kHz).
    """
    return convert_take(read_beat2(npz_path), fps)


def beat2_wav(npz_path: str | Path) -> Path | None:
    """The take's speech: ``../wave16k/<name>.wav`` in BEAT2's layout, else a same-named ``.wav`` beside it."""
    p = Path(npz_path)
    for cand in (p.parent.parent / AUDIO_DIR / f"{p.stem}.wav", p.with_suffix(".wav")):
        if cand.is_file():
            return cand
    return None


def find_takes(root: str | Path) -> dict[str, Path]:
    """BEAT2 takes under ``root``: name → npz, for every ``*.npz`` inside a ``smplxflame_30`` folder."""
    root = Path(root)
    out: dict[str, Path] = {}
    for p in sorted(root.rglob(f"{MOTION_DIR}/*.npz")):
        if p.is_file():
            if p.stem in out:
                raise file_error(p, f"take {p.stem} found twice: {out[p.stem]} and {p}")
            out[p.stem] = p
    return out


# ------------------------------------------------------------------ fitting on a pair
ELBOWS = (("RightForeArm", "right_elbow"), ("LeftForeArm", "left_elbow"))
MAX_LAG = 8  # source frames searched either way by measure_lag


def _angle(R: np.ndarray) -> np.ndarray:
    return rot.geodesic_angle(np.eye(3), R)


def measure_lag(poses: np.ndarray, src_fps: float, beat_local: np.ndarray, beat_fps: float) -> tuple[int, float]:
    """Source-frame lag k (and its mean r) where npz frame ``round(i·src/beat_fps) + k`` best matches BEAT frame i.

    Cross-correlation of both elbows' flexion angles (BEAT ForeArm rotation angle against
    the SMPL-X elbow's), over lags −MAX_LAG … MAX_LAG source frames.
    """
    L = rot.exp_so3(poses[:, [SMPLX_NAMES.index(s) for _, s in ELBOWS]])
    src = _angle(L)  # (Ts, 2)
    ref = _angle(beat_local[:, [UPPER_BODY.index(b) for b, _ in ELBOWS]])  # (Tb, 2)
    base = np.round(np.arange(len(ref)) * src_fps / beat_fps).astype(np.int64)
    best = (0, -2.0)
    for k in range(-MAX_LAG, MAX_LAG + 1):
        idx = base + k
        ok = (idx >= 0) & (idx < len(src))
        if ok.sum() < 10:
            continue
        r = float(np.mean([np.corrcoef(ref[ok, e], src[idx[ok], e])[0, 1] for e in range(len(ELBOWS))]))
        if r > best[1]:
            best = (k, r)
    return best


def aligned_pair(
    take: Beat2Take, beat_local: np.ndarray, beat_fps: float, lag: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M (N, 47, 3, 3), BEAT locals (N, 47, 3, 3), BEAT frame numbers (N,)) of the frames both have at ``lag``."""
    base = np.round(np.arange(len(beat_local)) * take.fps / beat_fps).astype(np.int64) + lag
    ok = np.flatnonzero((base >= 0) & (base < take.n_frames))
    return source_rotations(take.poses[base[ok]]), beat_local[ok], ok


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ‖a_i − R b_i‖² over vectors (N, 3) (Kabsch, scipy)."""
    from scipy.spatial.transform import Rotation

    return Rotation.align_vectors(a, b)[0].as_matrix()


def fit_joint(M: np.ndarray, L: np.ndarray, iters: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Constant (A, B) minimising Σ_t ‖A M_t B − L_t‖²_F over frames (T, 3, 3) (alternating Kabsch)."""
    A = np.eye(3)
    B = np.eye(3)
    for _ in range(iters):
        P = A @ M  # ‖P B − L‖ = ‖Bᵀ Pᵀ − Lᵀ‖: rows of P onto rows of L
        B = _align(L.reshape(-1, 3), P.reshape(-1, 3)).T
        Q = M @ B  # ‖A Q − L‖: columns of Q onto columns of L
        A_new = _align(np.swapaxes(L, -1, -2).reshape(-1, 3), np.swapaxes(Q, -1, -2).reshape(-1, 3))
        done = np.abs(A_new - A).max() < 1e-8
        A = A_new
        if done:
            break
    return A, B


def fit_corrections(M: np.ndarray, L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) (47, 3, 3) fitted on aligned frames: a joint without source gets its mean rotation."""
    left = np.broadcast_to(np.eye(3), (N_JOINTS, 3, 3)).copy()
    right = left.copy()
    for i, name in enumerate(UPPER_BODY):
        if SOURCES[name] is None:
            left[i] = rot.mean_rotation_matrix(L[:, i])
        else:
            left[i], right[i] = fit_joint(M[:, i], L[:, i])
    return left, right


def fit_twist(P: np.ndarray, L: np.ndarray) -> dict[str, np.ndarray]:
    """Per joint of :data:`TWIST_CHAINS`, the least-squares line from its chain's twists (P, corrected)
    to the residual twist of L about the same axis."""
    out: dict[str, np.ndarray] = {}
    for axis, chain in TWIST_CHAINS:
        X = twist_features(P, axis, chain)
        for n in chain:
            i = UPPER_BODY.index(n)
            y = rot.twist_angle(np.swapaxes(P[:, i], -1, -2) @ L[:, i], axis)
            out[n] = np.linalg.lstsq(X, y, rcond=None)[0]
    return out


def fit_jaw(theta: np.ndarray, target_mean: float, target_std: float) -> tuple[float, float]:
    """(offset, scale) of jawOpen = offset + scale·θ with mean/std ``target_*`` over ``theta`` (radians)."""
    sd = float(np.std(theta))
    if sd < 1e-9:
        raise UserError("the jaw does not move in the fitting frames: cannot fit jaw → jawOpen")
    scale = target_std / sd
    return float(target_mean - scale * np.mean(theta)), float(scale)


def angle_errors(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per-frame, per-joint angle (degrees) between two sets of rotation matrices (…, 3, 3)."""
    return np.degrees(rot.geodesic_angle(pred, ref))


#: BEAT's ARKit jawOpen over its 4-speaker training set (speakers 2, 4, 6, 8; CaMN's
#: face statistics, ``../shared/data/beat/stats/face_{mean,std}.npy`` channel 24).
BEAT_JAWOPEN_MEAN = 0.175998
BEAT_JAWOPEN_STD = 0.094629


def bvh_locals(bvh_path: str | Path) -> tuple[np.ndarray, float]:
    """Local rotations (T, 47, 3, 3) of a BEAT BVH's upper body, and its frame rate."""
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import local_matrices, motion_to_euler, upper_body_indices

    bvh = read_bvh(bvh_path)
    check_skeleton(bvh.skeleton, Path(bvh_path), None)
    _, euler = motion_to_euler(bvh.skeleton, bvh.motion)
    return local_matrices(bvh.skeleton, euler)[:, upper_body_indices(bvh.skeleton)], bvh.fps


def fit_map(npz_path: str | Path, bvh_path: str | Path, fit_fraction: float = 0.8) -> Beat2Map:
    """Fit the corrections on a calibration pair (a BEAT2 npz and the BEAT BVH of the same take).

    Only the first ``fit_fraction`` of the take is used (the lag, the per-joint rotations,
    the twist lines and the jaw line), so the rest can check the result.
    """
    take = read_beat2(npz_path)
    L, bfps = bvh_locals(bvh_path)
    n_fit = int(np.floor(len(L) * fit_fraction))
    lag, r = measure_lag(take.poses, take.fps, L[:n_fit], bfps)
    M, Lb, frames = aligned_pair(take, L[:n_fit], bfps, lag)
    left, right = fit_corrections(M, Lb)
    P = left[None] @ M @ right[None]
    twist = fit_twist(P, Lb)
    gains = fit_gains(redistribute_twist(P, twist), Lb)
    jaw = take.poses[: int(np.floor(take.n_frames * fit_fraction)), JAW, 0]
    off, scale = fit_jaw(jaw, BEAT_JAWOPEN_MEAN, BEAT_JAWOPEN_STD)
    info = {
        "name": MAP_NAME,
        "description": "SMPL-X (BEAT2) → BEAT upper body: L_j = left_j · M_j · right_j, then the arm twist "
        "and finger flexion lines, then the finger amplitude gains (facecapges.data.beat2). Quaternions (w, x, y, z).",
        "source": f"fitted on {take.path.name} + {Path(bvh_path).name} (BEAT speaker 2, CC BY-NC 4.0), "
        f"first {fit_fraction:.0%} of the take ({len(frames)} frames)",
        "licence": "CC BY-NC 4.0 (derived from BEAT / BEAT2)",
        "lag_source_frames": lag,
        "lag_elbow_r": round(r, 4),
    }
    return Beat2Map(left, right, off, scale, twist, info, gains)


def write_map(mapping: Beat2Map, path: str | Path, force: bool = False) -> Path:
    """Write a correction map as JSON (refuses to overwrite without ``force``)."""
    from facecapges.errors import refuse_overwrite

    p = Path(path)
    if p.exists():
        refuse_overwrite(p, force)
    p.write_text(json.dumps(mapping.to_dict(), indent=1) + "\n", encoding="utf-8")
    return p


#: Joint groups of the error report.
GROUPS: dict[str, tuple[str, ...]] = {
    "spine/neck/head": ("Spine", "Neck", "Neck1"),
    "shoulders/arms": tuple(f"{s}{j}" for s in ("Right", "Left") for j in ("Shoulder", "Arm", "ForeArm")),
    "hands": ("RightHand", "LeftHand"),
}
GROUPS["fingers"] = tuple(n for n in UPPER_BODY if not any(n in g for g in GROUPS.values()))


def pair_errors(
    npz_path: str | Path, bvh_path: str | Path, mapping: Beat2Map | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Angle errors (N, 47) in degrees of the converted take against the BVH, after the map's lag,
    and the BVH frame number of each row (N,)."""
    m = mapping or load_map()
    take = read_beat2(npz_path)
    L, bfps = bvh_locals(bvh_path)
    M, Lb, frames = aligned_pair(take, L, bfps, int(m.info.get("lag_source_frames", 0)))
    return angle_errors(corrected(M, m), Lb), frames


def group_figures(errors: np.ndarray) -> dict[str, tuple[float, float]]:
    """(median, 95th percentile) in degrees per joint group of :data:`GROUPS`, and ``"all"``."""
    out = {}
    for g, names in {**GROUPS, "all": UPPER_BODY}.items():
        e = errors[:, [UPPER_BODY.index(n) for n in names]]
        out[g] = (float(np.median(e)), float(np.percentile(e, 95)))
    return out
