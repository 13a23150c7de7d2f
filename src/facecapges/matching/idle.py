"""A pause like a person's (issue #38): ease into his rest pose and a small procedural idle while not speaking.

His monologue holds almost no long rest (docs/matching.md, "A pause like a person's"): the database's idle
rows are breaths mid-gesture or a stroke's run-up, so the search alone settles a pause late (2–4 s). This
layer sits on the matcher's output (step 7 of :mod:`facecapges.matching.matcher`); the matcher keeps
searching underneath, so speech picks up the matched motion at once.

Per stream and frame, from the matcher's pose ``q`` (after the dial) and the causal VAD's frames since the last
speech-like frame (``since_voice`` of :class:`facecapges.matching.speech.SpeechFrame`):

* **the target**: while the voice is on, ``q`` itself; once it has been gone ``after`` frames (the VAD's
  pause begins after ``HANGOVER`` = 6; the matcher's default 7), his rest pose
  with the procedural idle on top. The rest pose is the database's *rest* row (an idle row in the rest
  phase: wrists low and slow, :func:`facecapges.matching.database.gesture_phases`) nearest the pose shown
  when the pause begins — among the rest rows with both wrists low (``rest="low"``: a real frame of his, the
  shortest way there, and pauses that differ — hands clasped, both hanging, one at the belly) or among all
  rest rows (``rest="nearest"``: their mean wrist height is low, so one forearm may stay raised through the
  pause), or the quaternion mean of all rest rows (``rest="mean"``: one pose for every pause);
* **the switch** between the two is an inertialization (:mod:`facecapges.matching.inertialize`, as the
  matcher's clip switches): the offset that keeps the shown rotation and angular velocity across the switch
  decays with a critically damped spring, half-life ``enter_halflife_s`` into the pause and
  ``release_halflife_s`` back to the matched motion — no pose jumps, no stroke. Into a pause only
  ``enter_velocity`` of the matched motion's angular velocity is carried (the matcher's default 0: a stroke the
  voice stopped in does not run on into the pause); the step that removes the rest is an acceleration, and the
  acceleration cap (``acc_cap``: his 99th percentile) spreads it over frames, so the arms brake as fast as he
  ever does and no faster (docs/matching.md "Settling sooner");
* **the procedural idle** (:class:`IdleMotion`): on each arm's Shoulder, Arm, ForeArm and Hand (not the
  fingers: the BEAT2 rows' thumbs jitter) and, with ``torso=True``, on Spine, Neck and Neck1: per joint and
  axis a sum of two sines of fixed phases whose spread (sd) of angle and of angular velocity are **his**,
  measured in his rest rows (runs of ≥ :data:`MIN_RUN` rest rows, about each run's mean rotation; robust sd,
  :func:`robust_sd`), so the shoulders' small lift and the arms' drift come at his rest amplitude and speed,
  scaled by the dial's gain and ``amplitude``; with the style's skeleton, bounded so the idle moves the wrists
  no faster than the rest runs do (:meth:`IdleMotion.wrist_speed`: a capture's noise inflates the per-joint
  amplitudes, not the wrists' motion). By default (``torso=False``, the matcher's ``idle_torso``) the
  spine and neck keep the matched motion (his idle rows underneath): the head — the Spine → Neck → Neck1
  chain — moves in a pause as his does without a face track (with one, the runtime puts the captured head on
  it, :mod:`facecapges.runtime.head`); the procedural torso turned the head at 0.4× his speed (docs/matching.md).

Everything is a function of the stream's own state and frame count (no random state), so one stream and a
slot of a batch give the same poses.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from facecapges.matching import inertialize as inz
from facecapges.rotations import quaternion_to_rot6d
from facecapges.skeleton import N_JOINTS, TORSO, UPPER_BODY, Skeleton, upper_body_transforms

IDLE_JOINTS: tuple[str, ...] = TORSO + tuple(
    f"{side}{j}" for side in ("Right", "Left") for j in ("Shoulder", "Arm", "ForeArm", "Hand")
)
MIN_RUN = 6  # rest rows in a row (0.4 s) for a run to measure the idle's amplitude about its mean
FREQ_SPLIT = (0.75, float(np.sqrt(2.0 - 0.75**2)))  # two sines at f·0.75, f·1.2: RMS frequency f, sd = amplitude
PHASE_SEED = 38
SPENT = 1e-6  # rad, rad/s: an offset this small is spent (the stream shows the matched pose unchanged)
LOW_PERCENTILE = 40.0  # a rest pose's wrists are both below this percentile of their height (gesture_phases' "low")
WRISTS = ("RightHand", "LeftHand")  # the joints whose speed bounds the idle (IdleMotion.wrist_speed)
BOUND_POSES, BOUND_FRAMES = 16, 150  # the idle's wrist speed is measured on ≤ 16 rest poses over 10 s each
BOUND_PASSES = 4  # at most this many rescalings to bring the idle's wrist speed down to the rest runs'


def _wrist_speed(skel: Skeleton, q: np.ndarray, fps: float) -> np.ndarray:
    """Per frame step (T−1,) the mean speed of the two wrists for quaternion poses (T, 47, 4) on ``skel``."""
    _, p = upper_body_transforms(skel, quaternion_to_rot6d(q))
    w = p[:, [skel.index(n) for n in WRISTS]]
    return np.linalg.norm(np.diff(w, axis=0), axis=-1).mean(1) * fps


def rest_runs(segment: np.ndarray, rest_rows: np.ndarray) -> list[np.ndarray]:
    """The database's rows (indices) of each run of ≥ :data:`MIN_RUN` consecutive rest rows within one segment."""
    out = []
    for s in np.unique(segment):
        rows = np.flatnonzero(segment == s)
        d = np.diff(np.r_[0, rest_rows[rows].astype(np.int8), 0])
        out += [
            rows[a:b] for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True) if b - a >= MIN_RUN
        ]
    return out


def robust_sd(x: np.ndarray) -> np.ndarray:
    """Per column of ``x`` (n, …): 1.4826 · the median absolute deviation from the median (the sd of a
    normal sample, unmoved by the few fast frames at a rest run's edge, where a gesture starts or ends)."""
    return 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)


@dataclass(frozen=True)
class IdleMotion:
    """His idle, measured from a database's rest rows (module docs)."""

    joints: np.ndarray  # (J,) indices into the 47 joints
    amplitude: np.ndarray  # (J, 3) sd of the angle about the run's mean, rad (per local axis)
    frequency: np.ndarray  # (J, 3) Hz: sd of the angular velocity / (2π · sd of the angle)
    rest: np.ndarray  # (R, 47, 4) the rest poses a pause may settle into
    phase: np.ndarray  # (2, J, 3) fixed phases of the two sines

    @classmethod
    def measure(
        cls,
        row_quaternions: np.ndarray,
        segment: np.ndarray,
        rest_rows: np.ndarray,
        fps: float,
        rest: str = "low",
        wrist_height: np.ndarray | None = None,
        skeleton: Skeleton | None = None,
    ) -> IdleMotion:
        """From the database's rotations (N, 47, 4), segments (N,), rest rows (N,) bool and, for ``rest="low"``,
        the wrists' heights (N, 2) (the rest poses a pause settles into: rest rows with *both* wrists below the
        :data:`LOW_PERCENTILE` th percentile of that wrist's height — not one forearm raised). With the style's
        ``skeleton`` the amplitudes are bounded so the idle moves the wrists no faster than the rest runs do
        (:meth:`wrist_speed`)."""
        joints = np.array([UPPER_BODY.index(j) for j in IDLE_JOINTS])
        dev, vel = [], []
        runs = rest_runs(segment, rest_rows)
        for r in runs:
            q = row_quaternions[r][:, joints]
            mean = inz.quaternion_mean(q)
            dev.append(inz.qlog(inz.qabs(inz.qmul(inz.qconj(mean)[None], q))))
            vel.append(inz.angular_velocity(q, fps)[:-1])
        if not dev:  # no run long enough: no procedural idle (the rest pose alone)
            amp = np.zeros((len(joints), 3))
            freq = np.zeros((len(joints), 3))
        else:
            amp, speed = robust_sd(np.concatenate(dev)), robust_sd(np.concatenate(vel))
            freq = np.where(amp > 1e-6, speed / (2.0 * np.pi * np.maximum(amp, 1e-6)), 0.0)
        pick = rest_rows
        if rest == "low" and wrist_height is not None:
            low = (wrist_height <= np.percentile(wrist_height, LOW_PERCENTILE, axis=0)).all(axis=1)
            pick = rest_rows & low if (rest_rows & low).any() else rest_rows
        cand = row_quaternions[pick] if pick.any() else row_quaternions
        poses = inz.quaternion_mean(cand)[None] if rest == "mean" else cand
        phase = np.random.default_rng(PHASE_SEED).uniform(0.0, 2.0 * np.pi, (2, len(joints), 3))
        motion = cls(joints, amp, freq, np.ascontiguousarray(poses), phase)
        if skeleton is None or not runs:
            return motion
        rows_speed = float(np.mean(np.concatenate([_wrist_speed(skeleton, row_quaternions[r], fps) for r in runs])))
        for _ in range(BOUND_PASSES):  # the speed is nearly linear in the amplitude: a pass or two
            ratio = motion.wrist_speed(skeleton, fps) / max(rows_speed, 1e-9)
            if ratio <= 1.0:
                break
            motion = cls(joints, motion.amplitude / ratio, freq, motion.rest, phase)
        return motion

    def wrist_speed(self, skel: Skeleton, fps: float) -> float:
        """The mean wrist speed (cm/s for BEAT) of this idle at amplitude 1 on ≤ :data:`BOUND_POSES` of its rest
        poses, :data:`BOUND_FRAMES` frames each.

        **The wrist bound** (:meth:`measure` with a skeleton): the amplitudes are per joint and axis, measured
        apart, and the sines move every joint independently. In his motion capture that stays under his rest
        runs' wrist speed (beat2-scott-mm: the idle 12.8 cm/s against his rest runs' 14.8: the bound does not
        bind, its poses are unchanged). In a capture from video (``styles build --video``) the rest runs' arm
        rotations carry the solve's noise (the forearm's sd in a rest run up to 20°, median 9.7°; his real motion
        at the same frames up to 6°, median 3.6°) that barely shows at the wrist (the rest runs' wrists 12.1 cm/s, no faster than his): the elbow's
        swivel and the split of the bend between upper arm and forearm, which a camera hardly sees in depth.
        Replayed as independent sines it does move the wrists: 22.5 cm/s, 1.85× the style's own rest runs, and
        its pauses never settled (docs/capture-body.md, "Pauses that settle"). So every amplitude is scaled by one
        factor until the idle's mean wrist speed is at most the rest runs' (never up; the speed is nearly linear in
        the amplitude, so a few passes)."""
        k = np.linspace(0, len(self.rest) - 1, min(len(self.rest), BOUND_POSES)).round().astype(np.int64)
        t = np.arange(BOUND_FRAMES)
        one = np.ones(BOUND_FRAMES)
        return float(
            np.mean([np.mean(_wrist_speed(skel, self.pose(np.full(BOUND_FRAMES, i), t, fps, one), fps)) for i in k])
        )

    def offsets(self, t: np.ndarray, fps: float, scale: np.ndarray) -> np.ndarray:
        """Rotation vectors (B, J, 3) of the procedural idle at frames ``t`` (B,), amplitude × ``scale`` (B,)."""
        secs = np.asarray(t, np.float64)[:, None, None] / fps
        x = sum(np.sin(wk * secs + self.phase[i][None]) for i, wk in enumerate(self._angular))
        return self.amplitude[None] * x * np.asarray(scale, np.float64)[:, None, None]

    @functools.cached_property
    def _angular(self) -> tuple[np.ndarray, ...]:
        """The two sines' angular frequencies (1, J, 3) rad/s, ``2π · frequency · k`` (k of FREQ_SPLIT), made once."""
        w = 2.0 * np.pi * self.frequency[None]
        return tuple(w * k for k in FREQ_SPLIT)

    def pose(self, target: np.ndarray, t: np.ndarray, fps: float, scale: np.ndarray) -> np.ndarray:
        """Quaternions (B, 47, 4): rest poses ``target`` (B,) with the idle of frames ``t`` on top."""
        q = self.rest[target].copy()
        q[:, self.joints] = inz.qmul(q[:, self.joints], inz.qexp(self.offsets(t, fps, scale)))
        return q


class IdleLayer:
    """Per stream: the matcher's pose in, the pose shown out (module docs)."""

    def __init__(
        self,
        motion: IdleMotion,
        fps: float,
        *,
        after_frames: int,
        enter_halflife_s: float,
        release_halflife_s: float,
        amplitude: float = 1.0,
        acc_cap: float = 0.0,
        keep: tuple[str, ...] = (),
        enter_velocity: float = 1.0,
    ):
        self.motion, self.fps, self.acc_cap = motion, fps, acc_cap
        self.enter_velocity = enter_velocity  # the share of the matched motion's angular velocity carried into a pause
        self.keep = np.zeros(N_JOINTS, bool)  # joints that always show the matched motion
        self.keep[[UPPER_BODY.index(j) for j in keep]] = True
        self.after = max(int(after_frames), 1)
        self.enter_hl, self.release_hl, self.amplitude = enter_halflife_s, release_halflife_s, amplitude
        self.capacity = 0
        self.grow(1)
        from facecapges.matching import kernels  # Numba: loaded when a layer is built, not with this module

        self._step_offsets, self._pass, self._frame = kernels.step_offsets, kernels.idle_pass, kernels.idle_frame
        cap = self.acc_cap if self.acc_cap > 0 else -1.0
        self._layer = (self.after, float(self.fps), SPENT, cap, float(self.amplitude))  # idle_frame's constants
        w0, w1 = (w[0] for w in motion._angular)
        self._motion = np.ascontiguousarray(np.stack([motion.amplitude, w0, w1, motion.phase[0], motion.phase[1]]))

    def _compiled(self, ids, q, since_voice, t, gain) -> np.ndarray | None:
        """:meth:`apply`'s frame by a compiled call when it can (the same bits), else None: no stream in or
        entering a pause and every offset spent (zero: the matched poses as they are, most frames of speech), or no
        stream entering or leaving one (most frames of a pause)."""
        out = np.empty(q.shape, np.float64)
        state = (self.idle, self.x, self.v, self.prev_in, self.prev_out)
        if self._pass(ids, q, since_voice, self.after, *state, out):
            return out
        if self._frame(ids, q, since_voice, t, gain, self._layer, self._state(), self._motion, out):
            return out
        return None

    def _state(self) -> tuple:
        """What :func:`facecapges.matching.kernels.idle_frame` reads and updates, in its order."""
        m = self.motion
        return (self.idle, self.target, self.x, self.v, self.hl, self.prev_in, self.prev_out, m.rest, m.joints,
                self.keep)  # fmt: skip

    def grow(self, capacity: int) -> None:
        old = self.capacity
        if capacity <= old:
            return

        def g(name: str, shape: tuple, fill, dtype) -> np.ndarray:
            new = np.full((capacity, *shape), fill, dtype)
            if old:
                new[:old] = getattr(self, name)
            return new

        self.idle = g("idle", (), False, bool)  # the stream shows the rest + idle target
        self.target = g("target", (), 0, np.int64)  # its rest pose (index into motion.rest)
        self.x = g("x", (N_JOINTS, 3), 0.0, np.float64)  # the switch's offset and its velocity
        self.v = g("v", (N_JOINTS, 3), 0.0, np.float64)
        self.hl = g("hl", (), self.release_hl, np.float64)
        self.prev_in = g("prev_in", (N_JOINTS, 4), 0.0, np.float64)  # the matcher's last pose (its velocity)
        self.prev_out = g("prev_out", (2, N_JOINTS, 4), 0.0, np.float64)  # the last two poses shown (last: [1])
        self.capacity = capacity

    def restart(self, ids: np.ndarray, q: np.ndarray) -> None:
        """Streams ``ids`` start (again) at pose ``q`` (B, 47, 4), showing the matched motion."""
        self.idle[ids], self.target[ids], self.x[ids], self.v[ids] = False, 0, 0.0, 0.0
        self.hl[ids] = self.release_hl
        self.prev_in[ids], self.prev_out[ids] = q, q[:, None]

    def _velocity(self, q: np.ndarray, prev: np.ndarray) -> np.ndarray:
        return inz.qlog(inz.qabs(inz.qmul(q, inz.qconj(prev)))) * self.fps

    def _switch(self, ids, k, enter, q, idle_now, tgt, t, scale) -> None:
        """Streams ``ids[k]`` enter (``enter[k]``) or leave their rest pose this frame: the offset takes over the
        jump between the matched pose ``q`` and ``idle_now``, with each side's velocity (inertialization)."""
        matched_v = self._velocity(q[k], self.prev_in[ids[k]])
        idle_prev = self.motion.pose(tgt[k], t[k] - 1, self.fps, scale[k])
        idle_v = self._velocity(idle_now[k], idle_prev)
        idle_v[:, self.keep] = matched_v[:, self.keep]
        e = enter[k][:, None, None]
        src_q, dst_q = np.where(e, q[k], idle_now[k]), np.where(e, idle_now[k], q[k])
        # into a pause the matched motion's velocity is carried at ``enter_velocity`` (0: none — the step is
        # then an acceleration that the cap in apply spreads over frames); the kept joints keep theirs
        carried = np.where(self.keep[None, :, None], matched_v, matched_v * self.enter_velocity)
        src_v, dst_v = np.where(e, carried, idle_v), np.where(e, idle_v, matched_v)
        s = ids[k]
        self.x[s], self.v[s] = inz.transition(self.x[s], self.v[s], src_q, src_v, dst_q, dst_v)
        self.hl[s] = np.where(enter[k], self.enter_hl, self.release_hl)
        self.idle[s] = enter[k]

    def apply(
        self, ids: np.ndarray, q: np.ndarray, since_voice: np.ndarray, t: np.ndarray, gain: np.ndarray
    ) -> np.ndarray:
        """The shown poses (B, 47, 4) of streams ``ids`` from the matcher's ``q`` (B, 47, 4), the frames since
        their last speech-like frame ``since_voice`` (B,: :class:`facecapges.matching.speech.SpeechFrame`),
        frame counts ``t`` (B,) and the dial's gains (B,)."""
        out = self._compiled(ids, np.asarray(q, np.float64), since_voice, t, gain)
        if out is not None:
            return out
        want = np.asarray(since_voice) >= self.after
        was = self.idle[ids]
        m = self.motion
        scale = self.amplitude * np.asarray(gain, np.float64)
        enter, leave = want & ~was, ~want & was
        if enter.any():  # the rest pose nearest the pose shown now
            k = np.flatnonzero(enter)
            dist = np.sum(1.0 - np.abs(np.einsum("bjk,rjk->brj", self.prev_out[ids[k], 1], m.rest)), axis=2)
            self.target[ids[k]] = np.argmin(dist, axis=1)
        tgt = self.target[ids]
        out = np.array(q, np.float64)  # a stream the layer has let go of shows the matched pose as it is
        use = np.flatnonzero(was | want)  # streams whose rest pose is shown or switched from / to
        idle_now = out  # (read only, below, where no stream's rest pose is used: no copy needed then)
        if len(use):
            if len(use) == len(ids):  # every stream (use is then 0 … B − 1): the idle poses themselves
                idle_now = m.pose(tgt, t, self.fps, scale)
            else:
                idle_now = out.copy()
                idle_now[use] = m.pose(tgt[use], t[use], self.fps, scale[use])
            idle_now[:, self.keep] = q[:, self.keep]
        switch = enter | leave
        if switch.any():
            self._switch(ids, np.flatnonzero(switch), enter, q, idle_now, tgt, t, scale)
        # the offset still carries something: decay it and show it (else it is spent: zero, and q is shown)
        xs, vs = self.x[ids], self.v[ids]
        big = np.maximum.reduce  # ndarray.max's own reduction
        live = self.idle[ids] | (big(np.abs(xs), axis=(1, 2)) > SPENT) | (big(np.abs(vs), axis=(1, 2)) > SPENT)
        k = np.flatnonzero(live)
        if len(k) < len(ids):
            self.x[ids[~live]], self.v[ids[~live]] = 0.0, 0.0
        p1 = self.prev_out[ids, 1]
        if len(k):
            s = ids[k]
            base = np.where(self.idle[s][:, None, None], idle_now[k], q[k])
            shown = np.empty_like(base)
            # decay, exp(x) · base and the matcher's acceleration cap on what is shown (the offset takes up the rest)
            cap = self.acc_cap if self.acc_cap > 0 else -1.0
            self._step_offsets(s, self.x, self.v, self.hl, base, self.prev_out, cap, float(self.fps), False, shown)
            out[k] = shown
        out = inz.qabs(out)
        self.prev_in[ids], self.prev_out[ids, 0], self.prev_out[ids, 1] = q, p1, out
        return out
