"""iPhone Live Link Face (ARKit over UDP, default port 11111): packet decoder and receiver.

Packet layout implemented (Live Link Face's ARKit streaming mode, packet version 6;
Unreal's ``FArchive`` serialisation sent in network byte order — **big-endian**
throughout)::

    offset  type        field
    0       uint8       version (6)
    1       int32       n = byte length of the device id
    5       n bytes     device id, UTF-8 (the app's UUID, 36 characters)
    ..      int32       m = byte length of the subject name
    ..      m bytes     subject name, UTF-8 (the name set in the app, e.g. "iPhone")
    ..      int32       frame number      ┐ the frame time: FQualifiedFrameTime
    ..      float32     sub-frame         │ (time = (frame + sub-frame) · den / num)
    ..      int32       frame-rate numerator
    ..      int32       frame-rate denominator ┘
    ..      uint8       value count (61)
    ..      61 float32  values (below)

A packet with version 6 and a 36-byte id is 1 + 4+36 + 4+m + 16 + 1 + 244 bytes
(m = 13 → 319 bytes; the LLV recordings, 32-byte id and 18-byte name, are 320). The 61
values, in Apple's ``ARFaceAnchor.BlendShapeLocation`` order as Unreal's
``EARFaceBlendShape`` lists them (:data:`LIVELINK_NAMES`): the 52 blendshapes
(``EyeBlinkLeft`` … ``TongueOut``, weights in [0, 1]), then ``HeadYaw``, ``HeadPitch``,
``HeadRoll`` and the left/right eye yaw, pitch, roll.

Head angles: units and signs (settled on real recordings)
---------------------------------------------------------
The published sources disagree with a naive reading. Unreal's ARKit face support
(``ToBlendShapeMap`` in AppleARKitFaceSupport) turns the face transform into an
``FRotator`` and stores ``degrees / 180`` (so ±1 = ±180°), negating yaw and roll when the
face is *not* mirrored. The recordings of the app's packets in ``../shared/data/livelink/``
(the BSD-2 LLV project's ``.gesichter`` files) settle both questions:

* **Units: radians.** In ``dao.gesichter`` (180 frames of a real face) every eye angle is
  an exact linear function of the eye's ``EyeLook*`` weights (correlation 1.000): a full
  look (weight 1) is 0.61 of the angle unit. As radians that is 35°, the eye's real
  range; as degrees/180 it would be 110°, which no eye can do. The head, whose angles
  come from the same transform code, spans yaw −0.19…0.31, pitch −0.04…0.08 and roll
  −0.35…0.43: 11–25° as radians (a person talking and moving), 34–77° as degrees/180
  (a 77° roll would lay the head on the shoulder); as degrees it would be a head frozen
  within half a degree while the eyes sweep ±13°.
* **Signs: yaw and roll are negated, pitch kept.** Apple documents ``eyeLookInLeft`` and
  ``eyeLookOutRight`` as a *rightward* gaze, and both eyes' yaw grows with them: eye yaw
  > 0 is a gaze to the subject's right, eye pitch > 0 a gaze down. In the recording the
  head follows the eyes in both yaw (r = 0.98) and pitch (r = 0.65) with the eyes
  *leading* by 2–7 frames — ordinary eye-head gaze shifts, where eyes and head turn the
  same way — so head yaw > 0 turns the head to the subject's right and head pitch > 0
  tilts it down. Our convention (:mod:`facecapges.capture.head_pose`) has yaw > 0 to
  the subject's *left* and pitch > 0 down, so yaw changes sign. Roll changes sign with
  it: mirroring a face (the only thing Unreal's flag changes) negates yaw and roll
  together and never pitch, so whichever convention a packet is in, yaw and roll share
  their sign flip.

So the head → camera rotation is ``R = angles_to_matrix(−HeadYaw, HeadPitch, −HeadRoll)``
(:func:`facecapges.rotations.angles_to_matrix`: ``R_Y(yaw) @ R_X(pitch) @ R_Z(roll)``
in the ARKit-style camera frame, right-handed, Y up, +Z out of the face), then rot6d;
:attr:`LiveLinkFrame.head_angles` returns the angles already converted. ``tests/
test_runtime_livelink.py`` checks these figures on the recordings. The eye angles are
decoded but not used by the model. The 52 weights are reordered into
``facecapges.arkit.ARKIT_NAMES`` by name.

Robustness: :func:`decode_packet` raises :class:`PacketError` for anything that is not
one such packet (truncated, wrong version or count, lengths out of range, invalid UTF-8,
non-finite values). Bytes *after* the 61 values are ignored, as Unreal's receiver
ignores them (it reads the fields it knows and stops): a future app version may append
fields. :class:`LiveLinkReceiver` counts and drops bad packets and never stops on them.
A packet of another version is dropped too (counted as ``bad_packets``): the app's newer
MetaHuman mode uses another format.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass

import numpy as np

from facecapges import rotations as rot
from facecapges.arkit import N_BLENDSHAPES, arkit_index
from facecapges.runtime.os_threads import name_os_thread

DEFAULT_PORT = 11111
VERSION = 6
N_VALUES = 61
MAX_NAME_BYTES = 256  # longer id / subject fields are treated as malformed
MAX_SUBJECTS = 16  # subject names a receiver remembers (a sender picks them: memory must not follow)
_BLEND = [
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
]
LIVELINK_NAMES: tuple[str, ...] = tuple(
    _BLEND
    + [
        "HeadYaw",
        "HeadPitch",
        "HeadRoll",
        "LeftEyeYaw",
        "LeftEyePitch",
        "LeftEyeRoll",
        "RightEyeYaw",
        "RightEyePitch",
        "RightEyeRoll",
    ]
)
assert len(LIVELINK_NAMES) == N_VALUES
# index into the 61 values of each ARKIT_NAMES channel
_TO_ARKIT = np.zeros(N_BLENDSHAPES, np.int64)
for _i, _n in enumerate(_BLEND):
    _TO_ARKIT[arkit_index(_n)] = _i
assert sorted(_TO_ARKIT.tolist()) == list(range(N_BLENDSHAPES))

HEAD_SIGNS = np.array([-1.0, 1.0, -1.0])  # wire (HeadYaw, HeadPitch, HeadRoll) → ours (module docstring)
_TIME = struct.Struct(">ifii")
_VALUES = struct.Struct(f">{N_VALUES}f")


class PacketError(ValueError):
    """Bytes that are not one Live Link Face packet."""


@dataclass
class LiveLinkFrame:
    device_id: str
    subject: str
    frame_number: int
    sub_frame: float
    rate: tuple[int, int]  # (numerator, denominator)
    values: np.ndarray  # (61,) float32 as sent
    received_s: float = 0.0  # receiver's monotonic clock

    @property
    def time_s(self) -> float:
        """The frame time in seconds, ``(frame + sub-frame) · den / num``."""
        num, den = self.rate
        return (self.frame_number + self.sub_frame) * den / num if num > 0 and den > 0 else float("nan")

    @property
    def weights52(self) -> np.ndarray:
        """(52,) float32 in ARKIT_NAMES order, clipped to [0, 1]."""
        return np.clip(self.values[_TO_ARKIT], 0.0, 1.0).astype(np.float32)

    @property
    def head_angles(self) -> np.ndarray:
        """(yaw, pitch, roll) radians in the project's convention: the wire's yaw and roll negated (module docstring)."""
        return self.values[52:55].astype(np.float64) * HEAD_SIGNS

    @property
    def head_rot6d(self) -> np.ndarray:
        return rot.matrix_to_rot6d(rot.angles_to_matrix(*self.head_angles)).astype(np.float32)


def _string(data: bytes, pos: int, what: str) -> tuple[str, int]:
    if pos + 4 > len(data):
        raise PacketError(f"truncated before the {what} length")
    (n,) = struct.unpack_from(">i", data, pos)
    pos += 4
    if not 0 <= n <= MAX_NAME_BYTES:
        raise PacketError(f"{what} length {n} out of range")
    if pos + n > len(data):
        raise PacketError(f"truncated inside the {what}")
    try:
        s = data[pos : pos + n].decode("utf-8")
    except UnicodeDecodeError:
        raise PacketError(f"{what} is not UTF-8") from None
    return s, pos + n


def decode_packet(data: bytes) -> LiveLinkFrame:
    """One packet (layout in the module docstring; trailing bytes ignored) → :class:`LiveLinkFrame`.

    Raises :class:`PacketError` for anything else.
    """
    data = bytes(data)
    if len(data) < 1:
        raise PacketError("empty packet")
    if data[0] != VERSION:
        raise PacketError(f"packet version {data[0]} (expected {VERSION})")
    device, pos = _string(data, 1, "device id")
    subject, pos = _string(data, pos, "subject name")
    if pos + _TIME.size + 1 > len(data):
        raise PacketError("truncated inside the frame time")
    frame, sub, num, den = _TIME.unpack_from(data, pos)
    pos += _TIME.size
    count = data[pos]
    pos += 1
    if count != N_VALUES:
        raise PacketError(f"{count} values (expected {N_VALUES})")
    if pos + _VALUES.size > len(data):  # trailing bytes are ignored (module docstring)
        raise PacketError(f"{len(data) - pos} bytes of values (expected {_VALUES.size})")
    values = np.array(_VALUES.unpack_from(data, pos), np.float32)
    if not np.isfinite(values).all() or not np.isfinite(sub):
        raise PacketError("non-finite values")
    return LiveLinkFrame(device, subject, frame, sub, (num, den), values)


def encode_packet(
    values: np.ndarray,
    device_id: str = "00000000-0000-0000-0000-000000000000",
    subject: str = "iPhone",
    frame_number: int = 0,
    sub_frame: float = 0.0,
    rate: tuple[int, int] = (60, 1),
) -> bytes:
    """The inverse of :func:`decode_packet` (a sender for tools and demos)."""
    v = np.asarray(values, np.float32).reshape(-1)
    if v.shape[0] != N_VALUES:
        raise ValueError(f"need {N_VALUES} values, got {v.shape[0]}")
    d, s = device_id.encode(), subject.encode()
    return (
        struct.pack(">Bi", VERSION, len(d))
        + d
        + struct.pack(">i", len(s))
        + s
        + _TIME.pack(frame_number, sub_frame, *rate)
        + bytes([N_VALUES])
        + _VALUES.pack(*v.tolist())
    )


class LiveLinkReceiver:
    """UDP receiver thread: keeps the newest valid frame, counts and drops malformed packets.

    Binds ``host:port`` (127.0.0.1 unless the user asks for another address).
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1"):
        from facecapges.errors import UserError

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)  # absorb bursts (Wi-Fi clumps)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise UserError(f"Live Link receiver cannot listen on UDP {host}:{port} ({exc.strerror or exc})") from None
        self.sock.settimeout(0.1)
        self.address = self.sock.getsockname()
        self.packets = 0
        self.bad_packets = 0
        self.last_error = ""
        self.subjects: set[str] = set()  # the first MAX_SUBJECTS names seen
        self.other_subjects = 0  # packets of further names (not kept)
        self._latest: LiveLinkFrame | None = None
        self._seq = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="livelink-rx", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        name_os_thread("livelink-rx")
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    break
                continue
            try:
                fr = decode_packet(data)
            except PacketError as exc:
                with self._lock:
                    self.bad_packets += 1
                    self.last_error = str(exc)
                continue
            fr.received_s = time.monotonic()
            with self._lock:
                self.packets += 1
                if fr.subject not in self.subjects:
                    if len(self.subjects) < MAX_SUBJECTS:
                        self.subjects.add(fr.subject)
                    else:
                        self.other_subjects += 1  # counted, not kept: senders choose the names
                self._latest = fr
                self._seq += 1

    def latest(self) -> tuple[int, LiveLinkFrame | None]:
        """(sequence number, newest valid frame); the number grows by one per valid packet."""
        with self._lock:
            return self._seq, self._latest

    def stats(self) -> dict:
        with self._lock:
            return {"packets": self.packets, "bad_packets": self.bad_packets, "last_error": self.last_error}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()
