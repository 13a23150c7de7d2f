"""The face-lost policy: hold the last face, then ease it away — one definition for the whole project.

When no fresh face arrives (occlusion, the face left the frame, a stalled camera), what
the avatar shows is the last fresh face **held** for ``hold_s`` (0.5 s: a blink of an
occlusion should not make the avatar twitch), then **eased** over ``ease_s`` (1 s) to
what stands in for a face (weights 0 and the head facing the camera for the capture
and the model's input; the model's own head for the avatar's head,
:mod:`facecapges.runtime.head`). The ease is a smoothstep of the time since the last
fresh face, so position and speed are continuous at both ends; rotations ease along the
geodesic (the rotation raised to the factor, :func:`facecapges.rotations.rotation_power_about`).

When the face comes back, consumers that blend *towards* the face again (the avatar's
head) use :meth:`FaceLostPolicy.ease_in` over ``ease_in_s`` (0.3 s), also a smoothstep.

Used by :class:`facecapges.capture.FaceCapture` (per tracked face),
:class:`facecapges.runtime.scheduler.FaceHold` (a stalled input) and
:class:`facecapges.runtime.head.HeadDriver` (captured head ↔ model head).
"""

from __future__ import annotations

from dataclasses import dataclass

HOLD_S = 0.5
EASE_S = 1.0
EASE_IN_S = 0.3


def smoothstep(x: float) -> float:
    """``3x² − 2x³`` on [0, 1], clamped outside."""
    x = min(max(float(x), 0.0), 1.0)
    return x * x * (3 - 2 * x)


@dataclass(frozen=True)
class FaceLostPolicy:
    """Hold then ease (module docstring). Times in seconds."""

    hold_s: float = HOLD_S
    ease_s: float = EASE_S
    ease_in_s: float = EASE_IN_S

    @classmethod
    def from_ms(cls, hold_ms: float, ease_ms: float) -> FaceLostPolicy:
        return cls(hold_ms / 1000.0, ease_ms / 1000.0)

    def held(self, age_s: float) -> float:
        """How much of the last face remains ``age_s`` after it was last seen: 1 while
        held, smoothstep down to 0 at ``hold_s + ease_s``."""
        return 1.0 - smoothstep((age_s - self.hold_s) / max(self.ease_s, 1e-6))

    def ease_in(self, since_s: float) -> float:
        """Weight of a face that came back ``since_s`` ago: smoothstep 0 → 1 over ``ease_in_s``."""
        return smoothstep(since_s / max(self.ease_in_s, 1e-6))

    @property
    def gone_s(self) -> float:
        """After this long without a face, nothing of it remains."""
        return self.hold_s + self.ease_s
