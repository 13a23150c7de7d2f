"""The MOTION section's text of a block of frames, compiled (Numba): ``live``'s BVH recorder (issue 36).

A value's text is ``"%.6f" % v`` (:class:`facecapges.io.bvh.BvhWriter`'s): the decimal of v's exact binary value
correctly rounded to 6 places, half to even. Here it is the integer ``k = rint(|v| · 10⁶)`` written out — the
same digits unless the exact ``|v| · 10⁶`` lies within a few ulps of a half (the product's rounding could then
cross it), or |v| · 10⁶ ≥ 10¹⁵, or v is not finite: such a row is written by ``%`` itself. A sign is written when
v's sign bit is set (``-0.000000`` for −0.0 and for small negatives, as ``%`` writes them). :func:`checked` holds
it against ``%`` once a process; ``tests/test_skeleton_bvh.py`` on millions of values.
"""

from __future__ import annotations

import functools

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_WIDTH = 18  # bytes a value takes at most: a sign, 9 digits, the point, 6 decimals, a space


@_jit
def _format(motion: np.ndarray, buf: np.ndarray, bad: np.ndarray) -> int:
    """Rows of ``motion`` (n, C) as ASCII into ``buf``, values joined by spaces, rows by newlines; ``bad[i]`` when
    a value of row i needs ``%`` (module docstring). Returns the bytes written."""
    at = 0
    digits = np.empty(20, np.uint8)
    for i in range(motion.shape[0]):
        if i:
            buf[at] = 10  # \n
            at += 1
        for j in range(motion.shape[1]):
            v = motion[i, j]
            if j:
                buf[at] = 32
                at += 1
            if np.signbit(v):
                buf[at] = 45  # -
                at += 1
            y = abs(v) * 1e6
            if not y < 1e15:  # large, inf or NaN
                bad[i] = True
                y = 0.0
            k = np.rint(y)
            if abs(abs(y - k) - 0.5) <= 1e-15 * y + 1e-300:  # near a half: the exact value may be either side
                bad[i] = True
            q = np.int64(k)
            nd = 0
            while q or nd < 7:  # at least 7 digits: "0.000000"
                digits[nd] = 48 + q % 10
                q //= 10
                nd += 1
            for d in range(nd - 1, -1, -1):
                buf[at] = digits[d]
                at += 1
                if d == 6:
                    buf[at] = 46  # .
                    at += 1
    return at


def motion_lines(motion: np.ndarray) -> list[str]:
    """The MOTION lines of ``motion`` (n, C) float64: ``" ".join("%.6f" % v for v in row)`` of each row."""
    motion = np.ascontiguousarray(motion, np.float64)
    buf = np.empty(motion.size * _WIDTH + len(motion), np.uint8)
    bad = np.zeros(len(motion), np.bool_)
    n = _format(motion, buf, bad)
    lines = buf[:n].tobytes().decode("ascii").split("\n") if len(motion) else []
    for i in np.flatnonzero(bad).tolist():
        lines[i] = " ".join([f"{v:.6f}" for v in motion[i].tolist()])
    return lines


@functools.cache  # once a process
def checked() -> bool:
    """Whether :func:`motion_lines` writes ``%``'s text on this machine: random angles of every scale, halves,
    signed zeros, tiny negatives, integers, huge values, NaN and infinities."""
    rng = np.random.default_rng(0)
    m = rng.standard_normal((40, 200)) * 10.0 ** rng.integers(-9, 9, (40, 200))
    m[0, :8] = [0.0, -0.0, -1e-9, 1e-9, 0.0000005, -0.0000015, 0.0078125, -2.5e-6]
    m[1, :6] = [np.nan, np.inf, -np.inf, 1e15, 1e16, -180.0]
    m[2] = np.round(m[2], 6)
    m[3] = (rng.integers(-(10**9), 10**9, 200) + 0.5) / 1e6
    want = [" ".join([f"{v:.6f}" for v in row]) for row in m.tolist()]
    return motion_lines(m) == want
