"""``live --body``: the person's arms and hands where the camera sees them, the engine's gestures elsewhere.

Each camera frame the capture runs capture-body's landmarkers (:class:`~facecapges.capture.body.BodyLandmarker`:
MediaPipe's pose and two-hand landmarkers) and its solver frame by frame, causally
(:class:`~facecapges.capture.body_solve.StreamSolver`: One-Euro filtered landmarks, a per-joint confidence,
nothing from later frames). Then, **per arm** (right and left apart) — the joints ``{Side}Shoulder``,
``{Side}Arm``, ``{Side}ForeArm``, ``{Side}Hand`` and its fingers:

* **seen** — the shoulder, elbow and wrist inside the image with the landmarker's visibility ≥ 0.5 (the
  solver's arm and forearm confidence) for :data:`SEEN_FRAMES` frames in a row: the arm follows the
  solved rotations (the fingers the hand landmarker's, easing to open when it loses the hand);
* **not seen** (the hand left the frame, the person is gone, no fresh camera frame for :data:`HOLD_S`),
  or ``--gestures``: the engine's pose for that arm, as without ``--body``.

The switch, both ways, is an **inertialized hand-over** (:mod:`facecapges.matching.inertialize`, the
motion-matching engine's own blend): the arm keeps its rotation and angular velocity at the switch and
the offset decays with a critically damped spring of half-life :data:`HALFLIFE_S`. Leaving the body,
the source's "next frame" is its last seen frame carried on at its angular velocity (the frame where
the arm is lost has no trustworthy landmarks).

**Spine and head: the engine's spine, the face capture's head (as without ``--body``).** The body's
torso lean and turn are seen only through the landmarks' depth (noisy: capture-body smooths them over
~2 s, which live could only do with a lag), so the spine keeps the style's own sway, continuous across
hand-overs; the head is the face capture's (``--head``). The arms' solved rotations are relative to the
person's torso, so the arm's pose relative to the chest is the person's.
"""

from __future__ import annotations

import time
from array import array

import numpy as np

from facecapges import rotations as rot
from facecapges.matching import inertialize as inz
from facecapges.skeleton import UPPER_BODY, Skeleton

HALFLIFE_S = 0.5  # the hand-over's half-life: longer than the matcher's 0.3 s (its switches join similar poses; a person's arm and the engine's can be far apart)
SEEN_FRAMES = 2  # frames an arm must be seen in a row before it takes over from the engine
HOLD_S = 0.5  # without a fresh camera frame, the last body observation counts this long
SIDES = ("Right", "Left")
MAX_EVENTS = 1000  # hand-overs listed in the report (counted beyond)
MIN_CONFIDENCE = 0.5  # the solver's MIN_VISIBILITY: an arm's joints below it are not seen


def arm_joints(side: str) -> np.ndarray:
    """Indices in UPPER_BODY of one arm's joints: shoulder, arm, forearm, hand and fingers."""
    return np.array([k for k, n in enumerate(UPPER_BODY) if n.startswith(side)], np.intp)


class ArmHandover:
    """Per arm, the source (body or engine) and the inertialized switch between them (module docstring)."""

    def __init__(self, fps: float, halflife_s: float = HALFLIFE_S):
        self.fps, self.halflife = float(fps), float(halflife_s)
        n = len(UPPER_BODY)
        self.x, self.v = np.zeros((n, 3)), np.zeros((n, 3))  # the offsets' rotation vectors, angular velocity
        self.on_body = [False, False]
        self.seen_run = [0, 0]
        self.handovers = [0, 0]
        self.body_frames = [0, 0]
        self.events: list[tuple[int, str, str]] = []  # (frame, side, "body" | "gestures"): each hand-over
        self.t = 0
        self.joints = [arm_joints(s) for s in SIDES]
        self._prev_e: np.ndarray | None = None
        self._prev_b: np.ndarray | None = None
        self._vel_b = np.zeros((n, 3))
        self._good_q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        self._good_v = np.zeros((n, 3))

    def _velocity(self, q: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
        if prev is None:
            return np.zeros(q.shape[:-1] + (3,))
        return inz.angular_velocity(np.stack([prev, q]), self.fps)[0]

    def step(self, engine_q: np.ndarray, body_q: np.ndarray | None, seen: list[bool], gestures: bool) -> np.ndarray:
        """Quaternions (47, 4): the engine's pose ``engine_q`` with each arm from ``body_q`` where it is
        ``seen`` (None: no fresh body frame; the last is held), blended at every switch."""
        v_e = self._velocity(engine_q, self._prev_e)
        self._prev_e = engine_q
        if body_q is not None:
            self._vel_b = self._velocity(body_q, self._prev_b)
            self._prev_b = body_q
        out = engine_q.copy()
        for s, J in enumerate(self.joints):
            if body_q is not None and seen[s]:  # the arm's last seen frame and its velocity
                self._good_q[J], self._good_v[J] = body_q[J], self._vel_b[J]
            self.seen_run[s] = self.seen_run[s] + 1 if seen[s] and self._prev_b is not None else 0
            want = not gestures and (self.seen_run[s] >= SEEN_FRAMES or (self.on_body[s] and seen[s]))
            if want != self.on_body[s]:
                b_q, b_v = self._good_q[J], self._good_v[J]
                if self.on_body[s]:  # leaving the body: its last seen frame carried on at its velocity
                    src_q, src_v = inz.qmul(inz.qexp(b_v / self.fps), b_q), b_v
                    dst_q, dst_v = engine_q[J], v_e[J]
                else:
                    src_q, src_v, dst_q, dst_v = engine_q[J], v_e[J], b_q, b_v
                self.x[J], self.v[J] = inz.transition(self.x[J], self.v[J], src_q, src_v, dst_q, dst_v)
                self.on_body[s] = want
                self.handovers[s] += 1
                if len(self.events) < MAX_EVENTS:
                    self.events.append((self.t, SIDES[s], "body" if want else "gestures"))
            if self.on_body[s]:
                out[J] = self._good_q[J]
                self.body_frames[s] += 1
        self.x, self.v = inz.decay_spring(self.x, self.v, self.halflife, 1.0 / self.fps)
        self.t += 1
        return inz.qabs(inz.qmul(inz.qexp(self.x), out))


class LiveBody:
    """The body capture of ``live --body`` and its arms' hand-over (module docstring). Use :meth:`observe` on
    every camera frame the face capture sees, :meth:`apply` on every model frame's pose; :meth:`close`."""

    def __init__(self, skel: Skeleton, fps: float, gestures: bool = False):
        from facecapges.capture.body import BodyLandmarker
        from facecapges.capture.body_solve import StreamSolver

        self.fps = float(fps)
        self.gestures = bool(gestures)
        self.landmarker: BodyLandmarker | None = BodyLandmarker()
        self.solver = StreamSolver(skel, fps)
        self.handover = ArmHandover(fps)
        self.frames_seen = 0  # camera frames observed
        self.person_frames = 0  # … with a person found
        self.hand_frames = [0, 0]  # … with each hand found
        self.last_ms = 0.0  # the last observe's landmarkers + solve (ms)
        self.observe_ms = array("d")  # every observe's (8 bytes a camera frame)
        self._fresh: np.ndarray | None = None
        self._seen = [False, False]
        self._last_ts: float | None = None

    def observe(self, image_bgr: np.ndarray, ts_s: float) -> None:
        """Run the landmarkers and the causal solve on one camera frame (stamped ``ts_s``, stream time)."""
        from facecapges.capture.body import assign_hands, in_frame_visibility

        assert self.landmarker is not None, "closed"
        t = time.perf_counter()
        det = self.landmarker.detect(image_bgr, int(round(ts_s * 1000.0)))
        hands, scores = assign_hands(det)
        vis = in_frame_visibility(det)
        q, conf = self.solver.step(det["pose"], vis, hands, np.asarray(scores))
        self._fresh = q
        self._last_ts = ts_s
        idx = [UPPER_BODY.index(f"{s}{j}") for s in SIDES for j in ("Arm", "ForeArm")]
        self._seen = [bool(min(conf[idx[2 * s]], conf[idx[2 * s + 1]]) >= MIN_CONFIDENCE) for s in range(2)]
        self.frames_seen += 1
        self.person_frames += det["pose"] is not None
        for s in range(2):
            self.hand_frames[s] += scores[s] > 0
        self.last_ms = (time.perf_counter() - t) * 1000.0
        self.observe_ms.append(self.last_ms)

    def apply(self, pose: np.ndarray, now_s: float) -> np.ndarray:
        """The model's pose (47, 6) with each seen arm the person's (rot6d, float32)."""
        if self._last_ts is not None and now_s - self._last_ts > HOLD_S:
            self._seen = [False, False]  # no fresh camera frame for a while: a stalled camera is a person gone
        body, self._fresh = self._fresh, None
        q_e = rot.rot6d_to_quaternion(np.asarray(pose, np.float64))
        q = self.handover.step(q_e, body, self._seen, self.gestures)
        return rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)).astype(np.float32)

    @property
    def arms_on_body(self) -> list[bool]:
        return list(self.handover.on_body)

    def report(self) -> dict:
        """Counters for live's report: frames, person and hands found, frames each arm followed the body,
        hand-overs per arm."""
        from facecapges.runtime.scheduler import ms_stats

        n = max(self.frames_seen, 1)
        return {
            "observe_ms": ms_stats(self.observe_ms, skip=5),  # per camera frame seen (the scheduler's
            # stage ``body`` is 0 on frames whose camera frame was dropped)
            "camera_frames": self.frames_seen,
            "person_found": round(self.person_frames / n, 3),
            "hands_found": [round(h / n, 3) for h in self.hand_frames],
            "arm_frames_on_body": {s: self.handover.body_frames[k] for k, s in enumerate(SIDES)},
            "handovers": {s: self.handover.handovers[k] for k, s in enumerate(SIDES)},
            "handover_frames": [list(e) for e in self.handover.events],
            "gestures": self.gestures,
        }

    def close(self) -> None:
        if self.landmarker is not None:
            self.landmarker.close()
            self.landmarker = None
