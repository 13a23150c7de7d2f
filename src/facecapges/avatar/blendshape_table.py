"""Control-point tables: which vertices steer a blendshape, and where they go.

A table (JSON) drives :mod:`facecapges.avatar.blendshapes` for any neutral mesh::

    {
      "format": "facecapges-controls/1",
      "n_vertices": 468,              # the neutral mesh the indices refer to
      "units": "mesh units",          # displacements are in the mesh's own unit
      "controls": [61, 291, ...],     # every control point (0-based vertex index)
      "targets": {                    # per blendshape: displaced control points
        "jawOpen": {"152": [0.0, -1.9, -0.8], ...},
        ...
      }
    }

Every control point is constrained in **every** target: listed ones move by their
displacement, the others stay put (displacement 0), as the paper's 68 feature points
do for each of its blendshapes. One control set for all targets also lets the
deformation factor its matrix once for the whole table.

The shipped table ``facecapges/assets/arkit_controls.json`` is written by
:func:`author_arkit_table` from MediaPipe's canonical face mesh (centimetres, +X =
the subject's left, Y up, +Z out of the face) and its landmark indices: lips, lids,
brows, nose wings, cheeks, chin and the face outline (which holds the head's shape).
Each ARKit blendshape is a small rule in that function (e.g. ``eyeBlinkLeft``: the
upper lid of the subject's **left** eye meets the lower lid; ``jawOpen``: the jaw's
control points turn 16° about a hinge below the ears). ``tongueOut`` can only be
suggested on a face surface without a tongue: the jaw opens a little and the lower
lip is pushed down and forward. Regenerate the JSON with
``python -m facecapges.avatar.blendshape_table`` after editing the rules; a test
checks the shipped file matches them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from facecapges import rotations
from facecapges.arkit import ARKIT_NAMES
from facecapges.errors import UserError, file_error, require_file

FORMAT = "facecapges-controls/1"


def default_table_path() -> Path:
    """The shipped ARKit table for MediaPipe's canonical face mesh."""
    return Path(str(resources.files("facecapges") / "assets" / "arkit_controls.json"))


@dataclass
class ControlTable:
    """Control vertex indices (K,) and per-target displacements (K, 3) of all of them."""

    controls: np.ndarray
    targets: dict[str, np.ndarray]
    n_vertices: int

    @property
    def names(self) -> list[str]:
        return list(self.targets)


def parse_table(doc: dict, n_vertices: int, name: str | Path = "table") -> ControlTable:
    """Validate a table document against a mesh of ``n_vertices`` vertices."""
    if not isinstance(doc, dict) or "controls" not in doc or "targets" not in doc:
        raise file_error(name, "not a control table (needs 'controls' and 'targets')")
    try:
        controls = np.asarray([int(c) for c in doc["controls"]], np.int64)
    except (TypeError, ValueError):
        raise file_error(name, "'controls' must be a list of vertex indices") from None
    if controls.size == 0:
        raise file_error(name, "'controls' is empty")
    bad = controls[(controls < 0) | (controls >= n_vertices)]
    if bad.size:
        raise file_error(name, f"control index {int(bad[0])} is out of range for a mesh of {n_vertices} vertices")
    if np.unique(controls).size != controls.size:
        raise file_error(name, "'controls' lists a vertex twice")
    declared = doc.get("n_vertices")
    if declared is not None and int(declared) != n_vertices:
        raise file_error(name, f"table is for a mesh of {declared} vertices, this mesh has {n_vertices}")
    pos = {int(c): k for k, c in enumerate(controls)}
    targets: dict[str, np.ndarray] = {}
    if not isinstance(doc["targets"], dict) or not doc["targets"]:
        raise file_error(name, "'targets' must be a non-empty object of blendshape name → displacements")
    for tname, disp in doc["targets"].items():
        arr = np.zeros((controls.size, 3))
        if not isinstance(disp, dict):
            raise file_error(name, f"target {tname!r}: expected an object of vertex index → [dx, dy, dz]")
        for key, vec in disp.items():
            try:
                vi = int(key)
                d = np.asarray(vec, np.float64)
            except (TypeError, ValueError):
                raise file_error(name, f"target {tname!r}: bad entry {key!r}: {vec!r}") from None
            if vi < 0 or vi >= n_vertices:
                raise file_error(
                    name, f"target {tname!r}: vertex index {vi} is out of range for a mesh of {n_vertices} vertices"
                )
            if vi not in pos:
                raise file_error(name, f"target {tname!r}: vertex {vi} is not listed in 'controls'")
            if d.shape != (3,) or not np.all(np.isfinite(d)):
                raise file_error(name, f"target {tname!r}: vertex {vi} needs a finite [dx, dy, dz]")
            arr[pos[vi]] = d
        targets[str(tname)] = arr
    return ControlTable(controls, targets, n_vertices)


def load_table(path: str | Path, n_vertices: int) -> ControlTable:
    """Read and validate a table file (UserError on any problem)."""
    p = require_file(path, "control table")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise file_error(p, f"not valid JSON ({exc})") from None
    return parse_table(doc, n_vertices, p)


def require_arkit(table: ControlTable, name: str | Path = "table") -> None:
    missing = [n for n in ARKIT_NAMES if n not in table.targets]
    if missing:
        raise UserError(f"{name}: the avatar needs all 52 ARKit blendshapes; missing {missing}")


# ------------------------------------------------------------ the authored table
# MediaPipe face-mesh landmark indices (= canonical mesh vertices). "R" lists are the
# subject's right side (−X); the left side is the mirror image (+X).
LIP_OUTER_UPPER = [61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291]
LIP_OUTER_LOWER = [146, 91, 181, 84, 17, 314, 405, 321, 375]
LIP_INNER_UPPER = [78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308]
LIP_INNER_LOWER = [95, 88, 178, 87, 14, 317, 402, 318, 324]
EYE_UPPER = {"R": [246, 161, 160, 159, 158, 157, 173], "L": [466, 388, 387, 386, 385, 384, 398]}
EYE_LOWER = {"R": [7, 163, 144, 145, 153, 154, 155], "L": [249, 390, 373, 374, 380, 381, 382]}
EYE_CORNERS = {"R": [33, 133], "L": [263, 362]}
BROW = {"R": [70, 63, 105, 66, 107, 46, 53, 52, 65, 55], "L": [300, 293, 334, 296, 336, 276, 283, 282, 295, 285]}
BROW_INNER = {"R": [66, 107, 65, 55], "L": [296, 336, 295, 285]}
BROW_MID = {"R": [105, 52], "L": [334, 282]}
BROW_OUTER = {"R": [70, 63, 46, 53], "L": [300, 293, 276, 283]}
NOSE = [1, 4, 6, 168, 2, 164]
NOSE_WING = {"R": [48, 98, 64, 129], "L": [278, 327, 294, 358]}
CHEEK = {"R": [50, 205, 187, 123], "L": [280, 425, 411, 352]}
UNDER_EYE = {"R": [117, 101, 36], "L": [346, 330, 266]}
CHIN = [152, 175, 199, 200, 18, 83, 313, 32, 262, 201, 421]
FACE_OVAL = [
    10,
    338,
    297,
    332,
    284,
    251,
    389,
    356,
    454,
    323,
    361,
    288,
    397,
    365,
    379,
    378,
    400,
    377,
    152,
    148,
    176,
    149,
    150,
    136,
    172,
    58,
    132,
    93,
    234,
    127,
    162,
    21,
    54,
    103,
    67,
    109,
]


def _controls() -> list[int]:
    groups = [LIP_OUTER_UPPER, LIP_OUTER_LOWER, LIP_INNER_UPPER, LIP_INNER_LOWER, NOSE, CHIN, FACE_OVAL]
    for d in (EYE_UPPER, EYE_LOWER, EYE_CORNERS, BROW, NOSE_WING, CHEEK, UNDER_EYE):
        groups += [d["R"], d["L"]]
    out: list[int] = []
    for g in groups:
        out += [i for i in g if i not in out]
    return out


class _Authoring:
    """The targets being authored on the canonical face ``V`` (468, 3) cm, and the regions the rules use."""

    def __init__(self, V: np.ndarray) -> None:
        self.V = V
        self.sgn = {"L": 1.0, "R": -1.0}
        self.t: dict[str, dict[int, np.ndarray]] = {n: {} for n in ARKIT_NAMES}
        self.lips = LIP_OUTER_UPPER + LIP_OUTER_LOWER + LIP_INNER_UPPER + LIP_INNER_LOWER
        self.upper_lip = LIP_OUTER_UPPER[1:-1] + LIP_INNER_UPPER[1:-1]
        self.lower_lip = LIP_OUTER_LOWER + LIP_INNER_LOWER
        self.corners = {"R": [61, 78], "L": [291, 308]}
        self.corner_x = float(V[291, 0])
        self.jaw_pts = CHIN + self.lower_lip + [i for i in FACE_OVAL if V[i, 1] < -3.0 and i not in CHIN]
        self.jaw_w = [
            float(np.clip((-2.5 - V[i, 1]) / 3.0, 0.0, 1.0)) if i in FACE_OVAL and i not in CHIN else 1.0
            for i in self.jaw_pts
        ]
        self.half = self.corners["R"] + self.corners["L"]

    def add(self, name: str, idx: list[int], d, weight=None) -> None:
        """Add the displacement ``d`` (one, or one per index) to ``idx`` in target ``name``, times ``weight``."""
        t = self.t
        d = np.asarray(d, np.float64)
        for k, i in enumerate(idx):
            w = 1.0 if weight is None else float(weight[k])
            vec = d[k] if d.ndim == 2 else d
            t[name][i] = t[name].get(i, np.zeros(3)) + w * vec

    def lateral(self, idx: list[int], side: str) -> np.ndarray:
        """1 at the ``side`` mouth corner, ½ in the middle, 0 at the other corner."""
        x = self.V[idx, 0] * self.sgn[side]
        return np.clip(0.5 + 0.5 * x / self.corner_x, 0.0, 1.0)

    def jaw_rotation(self, idx: list[int], degrees: float, weight=None) -> np.ndarray:
        """Displacements turning points about the jaw hinge (x axis through y=0.5, z=-1.5)."""
        a = np.radians(degrees)
        p = self.V[idx] - np.array([0.0, 0.5, -1.5])
        d = p @ rotations.axis_angle_matrix("X", a).T - p
        return d if weight is None else d * np.asarray(weight)[:, None]


def author_arkit_table(V: np.ndarray) -> dict:
    """The 52 ARKit targets as control displacements on the canonical face ``V`` (468, 3) cm."""
    controls = _controls()
    a = _Authoring(V)
    for s in ("L", "R"):
        _one_side(a, s)
    _symmetric(a)
    t = a.t
    targets = {n: {str(i): [round(float(x), 5) for x in d] for i, d in sorted(t[n].items())} for n in ARKIT_NAMES}
    return {
        "format": FORMAT,
        "description": "ARKit blendshapes as control-point displacements on MediaPipe's canonical face mesh "
        "(written by facecapges.avatar.blendshape_table.author_arkit_table).",
        "n_vertices": int(V.shape[0]),
        "units": "centimetres (canonical face: +X subject's left, Y up, +Z out of the face)",
        "controls": controls,
        "targets": targets,
    }


def _one_side(a: _Authoring, s: str) -> None:
    """The targets of one side ``s`` (``L`` / ``R``): brows, cheeks, lids, gaze, mouth, jaw."""
    V, add, lateral, corners = a.V, a.add, a.lateral, a.corners
    upper_lip, lower_lip, lips, jaw_pts, jaw_w = a.upper_lip, a.lower_lip, a.lips, a.jaw_pts, a.jaw_w
    S, sx = {"L": "Left", "R": "Right"}[s], a.sgn[s]
    # brows
    add(f"browDown{S}", BROW[s], [-0.12 * sx, -0.45, 0.05])
    add(f"browDown{S}", BROW_INNER[s], [-0.1 * sx, -0.1, 0.05])
    add(f"browOuterUp{S}", BROW_OUTER[s], [0.0, 0.6, 0.0])
    add(f"browOuterUp{S}", BROW_MID[s], [0.0, 0.3, 0.0])
    # cheeks
    add(f"cheekSquint{S}", CHEEK[s] + UNDER_EYE[s], [0.0, 0.35, 0.1])
    add(f"cheekSquint{S}", EYE_LOWER[s], [0.0, 0.08, 0.0])
    # lids: blink closes the upper lid onto the lower one (97 % of the gap)
    gap = V[EYE_LOWER[s]] - V[EYE_UPPER[s]]
    add(f"eyeBlink{S}", EYE_UPPER[s], 0.8 * 0.97 * gap)
    add(f"eyeBlink{S}", EYE_LOWER[s], -0.2 * 0.97 * gap)
    add(f"eyeSquint{S}", EYE_LOWER[s], -0.35 * gap)
    add(f"eyeSquint{S}", EYE_UPPER[s], 0.12 * gap)
    add(f"eyeSquint{S}", UNDER_EYE[s], [0.0, 0.12, 0.0])
    add(f"eyeWide{S}", EYE_UPPER[s], [0.0, 0.28, 0.05], weight=[0.5, 0.8, 1, 1, 1, 0.8, 0.5])
    add(f"eyeWide{S}", EYE_LOWER[s], [0.0, -0.05, 0.0])
    add(f"eyeLookDown{S}", EYE_UPPER[s], [0.0, -0.18, 0.0])
    add(f"eyeLookDown{S}", EYE_LOWER[s], [0.0, -0.08, 0.0])
    add(f"eyeLookUp{S}", EYE_UPPER[s], [0.0, 0.16, 0.0])
    add(f"eyeLookUp{S}", EYE_LOWER[s], [0.0, 0.06, 0.0])
    # in = towards the nose (−sx), out = away from it
    add(f"eyeLookIn{S}", EYE_UPPER[s] + EYE_LOWER[s], [-0.1 * sx, 0.0, 0.0])
    add(f"eyeLookOut{S}", EYE_UPPER[s] + EYE_LOWER[s], [0.1 * sx, 0.0, 0.0])
    # mouth, one side
    add(f"mouthDimple{S}", corners[s], [0.2 * sx, 0.0, -0.35])
    add(f"mouthFrown{S}", corners[s], [0.05 * sx, -0.55, -0.05])
    add(f"mouthFrown{S}", LIP_OUTER_LOWER, [0.0, -0.2, 0.0], weight=lateral(LIP_OUTER_LOWER, s) ** 3)
    add(f"mouthLowerDown{S}", lower_lip, [0.0, -0.5, 0.05], weight=lateral(lower_lip, s) ** 1.5)
    add(f"mouthPress{S}", LIP_INNER_UPPER, [0.0, -0.15, -0.05], weight=lateral(LIP_INNER_UPPER, s))
    add(f"mouthPress{S}", LIP_INNER_LOWER, [0.0, 0.2, -0.05], weight=lateral(LIP_INNER_LOWER, s))
    add(f"mouthPress{S}", LIP_OUTER_LOWER, [0.0, 0.12, -0.1], weight=lateral(LIP_OUTER_LOWER, s))
    add(f"mouthSmile{S}", corners[s], [0.45 * sx, 0.7, -0.4])
    add(f"mouthSmile{S}", CHEEK[s], [0.05 * sx, 0.2, 0.1])
    add(f"mouthStretch{S}", corners[s], [0.55 * sx, -0.2, -0.1])
    add(f"mouthUpperUp{S}", upper_lip, [0.0, 0.45, 0.05], weight=lateral(upper_lip, s) ** 1.5)
    add(f"noseSneer{S}", NOSE_WING[s], [0.05 * sx, 0.35, 0.0])
    add(f"noseSneer{S}", BROW_INNER[s], [0.0, -0.12, 0.0])
    add(f"noseSneer{S}", upper_lip, [0.0, 0.1, 0.0], weight=lateral(upper_lip, s) ** 3)
    # jaw sideways: towards the subject's own side
    add(f"jaw{S}", jaw_pts, [0.6 * sx, 0.0, 0.0], weight=jaw_w)
    # whole mouth sideways
    add(f"mouth{S}", lips, [0.6 * sx, 0.0, 0.0])


def _symmetric(a: _Authoring) -> None:
    """The targets with no side: inner brows, cheek puff, jaw forward / open, the whole mouth's shapes."""
    V, add, jaw_rotation, corners, corner_x = a.V, a.add, a.jaw_rotation, a.corners, a.corner_x
    upper_lip, lower_lip, lips, jaw_pts, jaw_w, half = a.upper_lip, a.lower_lip, a.lips, a.jaw_pts, a.jaw_w, a.half
    add("browInnerUp", BROW_INNER["R"] + BROW_INNER["L"], [0.0, 0.6, 0.0])
    add("browInnerUp", BROW_MID["R"] + BROW_MID["L"], [0.0, 0.25, 0.0])
    add("cheekPuff", CHEEK["R"], [-0.5, 0.0, 0.35])
    add("cheekPuff", CHEEK["L"], [0.5, 0.0, 0.35])
    add("cheekPuff", upper_lip + lower_lip, [0.0, 0.0, 0.1])
    add("jawForward", jaw_pts, [0.0, 0.0, 0.6], weight=jaw_w)
    add("jawOpen", jaw_pts, jaw_rotation(jaw_pts, 16.0, jaw_w))
    add("jawOpen", half, jaw_rotation(half, 8.0))
    # mouthClose: the lips meet (the neutral canonical mouth is slightly parted)
    lip_gap = V[14, 1] - V[13, 1]
    add("mouthClose", LIP_INNER_UPPER[1:-1], [0.0, 0.5 * lip_gap, 0.0])
    add("mouthClose", LIP_INNER_LOWER, [0.0, -0.5 * lip_gap, 0.0])
    add("mouthClose", LIP_OUTER_LOWER, [0.0, -0.3 * lip_gap, 0.0])
    # funnel: lips forward and flared, corners in; pucker: lips forward and tight
    add("mouthFunnel", lips, [0.0, 0.0, 0.45])
    add("mouthFunnel", corners["R"], [0.45, 0.0, 0.0])
    add("mouthFunnel", corners["L"], [-0.45, 0.0, 0.0])
    add("mouthFunnel", LIP_OUTER_UPPER[1:-1] + LIP_INNER_UPPER[1:-1], [0.0, 0.18, 0.0])
    add("mouthFunnel", lower_lip, [0.0, -0.2, 0.0])
    add("mouthPucker", lips, [0.0, 0.0, 0.55])
    pucker_in = -0.45 * V[lips, 0] / corner_x
    add("mouthPucker", lips, np.c_[pucker_in, np.zeros(len(lips)), np.zeros(len(lips))])
    add("mouthPucker", LIP_INNER_UPPER[1:-1], [0.0, 0.5 * lip_gap, 0.0])
    add("mouthPucker", LIP_INNER_LOWER, [0.0, -0.5 * lip_gap, 0.0])
    add("mouthRollLower", LIP_OUTER_LOWER, [0.0, 0.3, -0.4])
    add("mouthRollLower", LIP_INNER_LOWER, [0.0, 0.1, -0.3])
    add("mouthRollUpper", LIP_OUTER_UPPER[1:-1], [0.0, -0.3, -0.4])
    add("mouthRollUpper", LIP_INNER_UPPER[1:-1], [0.0, -0.1, -0.3])
    add("mouthShrugLower", lower_lip, [0.0, 0.3, 0.2])
    add("mouthShrugLower", [i for i in CHIN if V[i, 1] > -8.0], [0.0, 0.2, 0.15])
    add("mouthShrugUpper", upper_lip, [0.0, 0.25, 0.15])
    add("tongueOut", jaw_pts, jaw_rotation(jaw_pts, 6.0, jaw_w))
    add("tongueOut", lower_lip, [0.0, -0.3, 0.35])


def main() -> None:
    """Rewrite the shipped table from the rules above."""
    from facecapges.avatar.mesh import canonical_face

    doc = author_arkit_table(canonical_face().vertices)
    out = Path(__file__).resolve().parents[1] / "assets" / "arkit_controls.json"
    out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out} ({len(doc['controls'])} controls, {len(doc['targets'])} targets)")


if __name__ == "__main__":
    main()
