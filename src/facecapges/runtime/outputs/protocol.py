"""The WebSocket message format of the runtime, shared by the viewer feed and ``serve``.

Every message is one JSON text frame (UTF-8) holding one object with a ``"type"``;
a message is at most :data:`MAX_MESSAGE_BYTES` (64 KiB) — servers close a connection
that sends a larger one (WebSocket close code 1009, "message too big"). Version
:data:`PROTOCOL` = 1. Numbers are plain JSON numbers except audio, which is base64 of
little-endian float32 samples (a frame of 1067 samples is 5.7 KB instead of ~12 KB).

Server → client
---------------
``hello`` — sent once when a client connects::

    {"type": "hello", "protocol": 1, "fps": 15, "sr": 16000, "samples_per_frame": 1067,
     "joints": [47 names, facecapges.skeleton.UPPER_BODY order],
     "blendshapes": [52 names, facecapges.arkit.ARKIT_NAMES order],
     "max_message_bytes": 65536, "intensity": 1.0}

``status`` — ``serve`` only, before ``hello`` while the server is still loading its style::

    {"type": "status", "state": "loading", "message": "loading style …; hello follows when it is ready"}

A client reads messages until ``hello``: the ``hello`` means the server is ready for input.

``intensity`` — the gesture intensity now (0 … 1.3, :mod:`facecapges.engine.intensity`); also sent as
``{"type": "intensity", "value": v}`` in reply to a client's ``intensity`` message.

``pose`` — one output frame (the viewer's feed; ``serve``'s reply to an ``input``)::

    {"type": "pose", "frame": k, "time": k / fps,
     "pose": [47 × (w, x, y, z)],      # local joint rotations, flat, BVH right-handed frame
     "weights": [52 floats],           # ARKit blendshape weights shown on the face
     "head": [6 floats],               # head rotation rot6d (head → camera)
     "face_found": true,
     "face": 0,                        # which face / avatar, 0-based (several with `live --faces N`)
     "latency_ms": {"capture": .., "features": .., "model": .., "total": ..},
                                       # compute of this frame; total = input frame → pose +
                                       # blendshapes ready (sending is not included)
     "sent_ms": 1732240000123.4}       # server wall clock (ms since the epoch) when sent

Client → server
---------------
``input`` — one frame of inputs for ``serve``::

    {"type": "input", "frame": k, "audio": "<base64 float32 LE, ≤ samples_per_frame>",
     "face": [52 floats], "head": [6 floats]}

``resume`` — ``{"type": "resume", "pose": [47 × (w, x, y, z)]}``: ``serve`` only, sent after ``hello``
and before the first ``input`` by a client that lost its connection (a server or cluster node died)
and reconnected: ``pose`` is the last ``pose`` it received (the same flat layout). The new stream
starts from that pose and blends into its own motion (the engines' inertialized start), so the
avatar does not jump at the hand-over. Without it a stream starts from the style's rest pose.
The server answers ``{"type": "resumed"}``. docs/serve-cluster.md.

``ping`` — ``{"type": "ping"}``; the server answers ``{"type": "pong", "sent_ms": ..}``.

``intensity`` — ``{"type": "intensity", "value": 0.8}``: the gesture intensity dial, 0 (rest / idle
only) … 1 (as the style moves) … 1.3; ``serve`` applies it to that client's stream, the viewer of
``live`` to every avatar (its slider sends it). The server answers with the value it applied.

Malformed client messages raise :class:`ProtocolError` in :func:`decode_client`; a
server answers ``{"type": "error", "message": ..}`` and keeps the connection.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import time
from collections.abc import Iterator, Sequence

import numpy as np
import orjson
import pybase64

from facecapges import timing
from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES
from facecapges.errors import UserError
from facecapges.runtime.frames import InputFrame, OutputFrame

# facecapges.skeleton (the joint names of the hello, the pose width) is imported where it is used: it
# imports torch, and ``serve`` answers handshakes (and says "loading") before torch has loaded.

PROTOCOL = 1
MAX_MESSAGE_BYTES = 64 * 1024


class ProtocolError(ValueError):
    """A client message that is not a valid protocol message."""


_SCALE = tuple(10.0**nd for nd in range(7))  # exact powers of ten (_r)


def _r(x: float, nd: int) -> float:
    """``round(float(x), nd)`` (0 ≤ nd ≤ 6), the same float, without its decimal conversion (3.5 K instructions of
    ``serve``'s per stream-frame cost, six per ``pose``): ``round`` takes the integer k nearest to x·10^nd (half to
    even, on x's exact value) and returns the float nearest to k / 10^nd, which the division gives (both exact,
    IEEE rounds it correctly). x·10^nd is off by at most half an ulp, so k is the same unless that product lies
    within a few ulps of a half — then, and for huge or non-finite values, ``round`` itself decides."""
    x = float(x)
    y = x * _SCALE[nd]
    if -1e15 < y < 1e15:
        k = round(y)
        if abs(abs(y - k) - 0.5) > 1e-15 * abs(y) + 1e-300:
            return k / _SCALE[nd] if k else math.copysign(0.0, x)
    return round(x, nd)


def encode_hello(fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR, intensity: float = 1.0) -> str:
    return json.dumps(
        {
            "type": "hello",
            "protocol": PROTOCOL,
            "fps": fps,
            "sr": sr,
            "samples_per_frame": timing.samples_per_frame(fps, sr),
            "joints": list(_upper_body()),
            "blendshapes": list(ARKIT_NAMES),
            "max_message_bytes": MAX_MESSAGE_BYTES,
            "intensity": intensity,
        }
    )


def _upper_body() -> tuple[str, ...]:
    from facecapges.skeleton import UPPER_BODY

    return tuple(UPPER_BODY)


def encode_status(state: str, message: str) -> str:
    """The ``status`` message ``serve`` sends before ``hello`` while it loads (module docs)."""
    return json.dumps({"type": "status", "state": state, "message": message})


def encode_intensity(value: float) -> str:
    """The server's ``intensity`` message: the value now applied."""
    return json.dumps({"type": "intensity", "value": round(float(value), 4)})


def encode_pose(out: OutputFrame) -> str:
    """One :class:`OutputFrame` as a ``pose`` message: :func:`encode_poses_utf8`'s text for one frame (the same
    rounding and the same message), without a batch of one around it."""
    return encode_pose_utf8(out).decode()


def encode_pose_utf8(out: OutputFrame) -> bytes:
    """:func:`encode_pose`'s message as UTF-8, what ``live``'s viewer feed sends as a text frame once a model frame
    (no decoding here and encoding again in the server's thread, issue 36)."""
    q, w, h = _rounded(out.quats, out.face, out.head, 1)
    return _pose_json(out.index, out.time_s, q[0], w[0], h[0], out.face_found, out.face_index, out.latency_ms)


def encode_poses_utf8(
    frames: Sequence[int],
    times_s: Sequence[float],
    quats: np.ndarray,
    faces: np.ndarray,
    heads: np.ndarray,
    face_found: Sequence[bool],
    latency_ms,
    face_index: Sequence[int] | None = None,
) -> Iterator[bytes]:
    """The ``pose`` messages of B output frames as UTF-8 bytes, what a WebSocket text frame carries
    (``serve`` writes them as they are: no decoding and encoding again; a sender that takes text decodes them).
    The one pose encoder: :func:`encode_pose` is its one-frame use. ``quats`` (B, 47, 4), ``faces``
    (B, 52), ``heads`` (B, 6) are rounded at once (6, 5 and 6 decimals). ``latency_ms``: B dicts, or a
    function of the row called just before that row is encoded (so a caller that sends each message as
    it comes reports its true latency). ``face_index``: which face / avatar each row is (``live --faces
    N``); 0 for all by default.
    """
    B = len(frames)
    q, w, h = _rounded(quats, faces, heads, B)
    lat = latency_ms if callable(latency_ms) else latency_ms.__getitem__
    for i in range(B):  # orjson: the same compact JSON as json.dumps, ~8x faster (it is serve's cost per frame)
        face = face_index[i] if face_index is not None else 0
        yield _pose_json(frames[i], times_s[i], q[i], w[i], h[i], face_found[i], face, lat(i))


_SCALES: dict[tuple[int, int, int], np.ndarray] = {}  # 10**decimals of each number of a row, by the parts' widths


def _rounded(quats, faces, heads, B: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B frames' quaternions, weights and heads as the ``pose`` message writes them: (B, ·) rows rounded to 6, 5
    and 6 decimals, the first two as float32 where every number is within [-1, 1] (below)."""
    # rows of C-contiguous arrays, written by orjson itself (OPT_SERIALIZE_NUMPY: the same text as the rows'
    # Python floats, without making ~250 float objects a frame: issue 36, serve's cost per stream-frame)
    parts = [np.asarray(a, np.float64).reshape(B, -1) for a in (quats, faces, heads)]
    nq, nw, nh = (p.shape[1] for p in parts)
    scale = _SCALES.get((nq, nw, nh))
    if scale is None:
        scale = _SCALES[nq, nw, nh] = np.repeat([1e6, 1e5, 1e6], [nq, nw, nh])
    # np.round(x, d) is rint(x · 10**d) / 10**d (NumPy's own steps): the three parts at once, each by its own 10**d
    r = np.rint(np.concatenate(parts, axis=1) * scale)
    r /= scale
    q, w, h = r[:, :nq], r[:, nq : nq + nw], r[:, nq + nw :]
    # within [-1, 1] a number of 6 decimals written from float32 (half the cost of float64's shortest text) reads
    # back as the same float64 — checked for every one of them (test_serve_server.py); the text differs only for
    # ±1e-6 … ±9e-6, written '0.000005' instead of '5e-6'. The head (a client's own numbers) stays float64.
    q, w = (a.astype(np.float32) if a.size and a.min() >= -1.0 and a.max() <= 1.0 else a for a in (q, w))
    return q, w, h


def _pose_json(frame, time_s, q, w, h, face_found, face, latency: dict) -> bytes:
    """One ``pose`` message as UTF-8 (``q``, ``w``, ``h``: a row of :func:`_rounded`)."""
    return orjson.dumps(
        {
            "type": "pose",
            "frame": int(frame),
            "time": _r(time_s, 6),
            "pose": q,
            "weights": w,
            "head": h,
            "face_found": bool(face_found),
            "face": int(face),
            "latency_ms": {k: _r(v, 3) for k, v in latency.items()},
            "sent_ms": _r(time.time() * 1000.0, 1),
        },
        option=orjson.OPT_SERIALIZE_NUMPY,
    )


def tick_latency(queued: float, t0: float, t1: float) -> dict:
    """A pose message's ``latency_ms`` for a batched tick (``serve``, ``serve --ray``): its input waited from
    ``queued`` to the tick's model call at ``t0``, the model ran until ``t1``, the output until now (monotonic s)."""
    now = time.monotonic()
    return {
        "queue": (t0 - queued) * 1e3,
        "model": (t1 - t0) * 1e3,
        "output": (now - t1) * 1e3,
        "total": (now - queued) * 1e3,
    }


def encode_input(frame: int, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> str:
    a = np.ascontiguousarray(np.asarray(audio, np.float32).reshape(-1)).astype("<f4")
    return json.dumps(
        {
            "type": "input",
            "frame": int(frame),
            "audio": base64.b64encode(a.tobytes()).decode("ascii"),
            "face": [float(v) for v in np.asarray(face).reshape(-1)],
            "head": [float(v) for v in np.asarray(head).reshape(-1)],
        },
        separators=(",", ":"),
    )


def _floats(obj, n: int, what: str) -> np.ndarray:
    if not isinstance(obj, list) or len(obj) != n:
        raise ProtocolError(f"'{what}' must be a list of {n} numbers")
    try:
        a = np.array(obj, dtype=np.float64)
    except (TypeError, ValueError):
        raise ProtocolError(f"'{what}' must hold numbers only") from None
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ProtocolError(f"'{what}' must hold {n} finite numbers")
    return a.astype(np.float32)


def _intensity(value) -> float:
    from facecapges.engine.intensity import check_intensity

    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ProtocolError("'value' of an intensity message must be a number")
    try:
        return check_intensity(value, "'value'")  # the dial's one range check
    except UserError as exc:
        raise ProtocolError(str(exc)) from None


RESUMED = '{"type":"resumed"}'  # the server's answer to a ``resume``


def _resume_pose(obj) -> np.ndarray:
    """A ``resume`` message's ``pose`` (47 × (w, x, y, z), flat) as rot6d (47, 6)."""
    from facecapges import rotations as rot

    n = len(_upper_body())
    q = _floats(obj, 4 * n, "pose").astype(np.float64).reshape(n, 4)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    if not np.all(norm > 1e-6):
        raise ProtocolError("'pose' of a resume message holds a zero quaternion")
    return np.asarray(rot.matrix_to_rot6d(rot.quaternion_to_matrix(q / norm)), np.float32)


_all = np.logical_and.reduce  # ndarray.all without its Python wrapper (a third of the time on 1067 samples)


def decode_client(text: str | bytes, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR) -> dict:
    """Parse a client message: ``{"type": "ping"}``, ``{"type": "intensity", "value": v}``,
    ``{"type": "resume", "pose": rot6d (47, 6)}`` or ``{"type": "input", "input": InputFrame}``."""
    if isinstance(text, (bytes, bytearray)):
        raise ProtocolError("binary messages are not part of the protocol (send JSON text)")
    # a code point is at most 4 bytes of UTF-8: a message of ≤ 16 Ki code points (an input is ~6.6 K) is not counted
    if len(text) > MAX_MESSAGE_BYTES // 4 and len(text.encode("utf-8", "replace")) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message larger than {MAX_MESSAGE_BYTES} bytes")
    try:
        msg = orjson.loads(text)  # ~7x faster than json.loads; every fault (depth, huge integers) is this error
    except json.JSONDecodeError as exc:  # orjson.JSONDecodeError is one
        if "recursion" in exc.msg:  # '[[[[…' deeper than the parser goes: bad input, not a crash
            raise ProtocolError("JSON nested too deeply") from None
        raise ProtocolError(f"not JSON ({exc.msg})") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise ProtocolError("a message must be a JSON object with a string 'type'")
    kind = msg["type"]
    if kind == "ping":
        return {"type": "ping"}
    if kind == "intensity":
        return {"type": "intensity", "value": _intensity(msg.get("value"))}
    if kind == "resume":
        return {"type": "resume", "pose": _resume_pose(msg.get("pose"))}
    if kind != "input":
        raise ProtocolError(f"unknown message type {kind!r} (expected 'input', 'intensity', 'resume' or 'ping')")
    k = msg.get("frame")
    if not isinstance(k, int) or isinstance(k, bool) or k < 0:
        raise ProtocolError("'frame' must be a non-negative integer")
    audio_b64 = msg.get("audio")
    if not isinstance(audio_b64, str):
        raise ProtocolError("'audio' must be a base64 string of float32 little-endian samples")
    try:  # the alphabet and the padding checked, as base64.b64decode(validate=True), in SIMD C (pybase64)
        raw = pybase64.b64decode(audio_b64, validate=True)
    except (binascii.Error, ValueError):
        raise ProtocolError("'audio' is not valid base64") from None
    spf = timing.samples_per_frame(fps, sr)
    if len(raw) % 4 or len(raw) // 4 > spf:
        raise ProtocolError(f"'audio' must hold at most {spf} float32 samples, got {len(raw) / 4:g}")
    audio = np.frombuffer(raw, dtype="<f4").astype(np.float32)
    if not _all(np.isfinite(audio)):
        raise ProtocolError("'audio' holds NaN or infinite samples")
    face, head = _face_head(msg.get("face"), msg.get("head"))
    return {"type": "input", "input": InputFrame(k, audio, face.clip(0.0, 1.0), head)}


def _face_head(face, head) -> tuple[np.ndarray, np.ndarray]:
    """An input's ``face`` (52) and ``head`` (6, a rotation) as float32, checked in one step (one array of
    the 58 numbers: ``serve``'s cost per stream-frame); anything else goes the field-by-field way of
    :func:`_floats` and :func:`_rotation`, which find and name the fault as before."""
    if type(face) is list and type(head) is list and len(face) == N_BLENDSHAPES and len(head) == 6:
        try:
            both = np.array(face + head, dtype=np.float64)
        except (TypeError, ValueError):
            both = None
        if both is not None and both.shape == (N_BLENDSHAPES + 6,) and _all(np.isfinite(both)):
            both = both.astype(np.float32)
            x0, x1, x2, y0, y1, y2 = both[N_BLENDSHAPES:].tolist()
            # columns' squared lengths far from 1e-12 (the check's bound) and from float32's overflow: a
            # rotation, whatever float32's rounding; closer to either, the check itself decides
            if 1e-10 < x0 * x0 + x1 * x1 + x2 * x2 < 1e30 and 1e-10 < y0 * y0 + y1 * y1 + y2 * y2 < 1e30:
                return both[:N_BLENDSHAPES], both[N_BLENDSHAPES:]
    return _floats(face, N_BLENDSHAPES, "face"), _rotation(_floats(head, 6, "head"))


def _rotation(head: np.ndarray) -> np.ndarray:
    """``head`` if it is a rot6d (both columns nonzero), else the ProtocolError."""
    a, b = head[:3], head[3:]  # np.linalg.norm's own steps (sqrt of the dot), without its checks
    if np.sqrt(a.dot(a)) < 1e-6 or np.sqrt(b.dot(b)) < 1e-6 or not math.isfinite(float(head.sum())):
        raise ProtocolError("'head' is not a rotation (a rot6d column is zero)")
    return head


def decode_pose(text: str) -> dict:
    """Parse a ``pose`` message (for clients and tests): arrays as numpy; ProtocolError if it is not one."""
    try:
        msg = orjson.loads(text)
    except ValueError:  # orjson.JSONDecodeError, whatever the fault (depth included)
        raise ProtocolError("not a JSON message") from None
    if not isinstance(msg, dict) or msg.get("type") != "pose":
        raise ProtocolError(f"not a pose message: {msg.get('type') if isinstance(msg, dict) else msg!r:.40}")
    try:
        msg["pose"] = np.asarray(msg["pose"], np.float64).reshape(len(_upper_body()), 4)
        msg["weights"] = np.asarray(msg["weights"], np.float64).reshape(N_BLENDSHAPES)
        msg["head"] = np.asarray(msg["head"], np.float64).reshape(6)
    except (KeyError, TypeError, ValueError):
        raise ProtocolError("a pose message needs 'pose' (47 × 4), 'weights' (52) and 'head' (6) numbers") from None
    return msg
