"""The per-frame Mel features without torch: their constants, the stored Mel filter bank, and
:func:`mel_features`, the same 43 numbers as :class:`facecapges.network.audio_features.AudioFeatures`
(whose module docs define them) computed in NumPy.

Why a second schedule of the same computation: the motion-matching engine's speech predictor runs without torch
at ``live`` time (:mod:`facecapges.matching.predictor`), so a matching style never loads torch (~85 MB of
libraries) for one 1067-sample frame a step. The FFTs are NumPy's (SciPy's for batches); everything between them
is the streaming kernel's compiled loops (:func:`~facecapges.network.native.mel_energy`,
:func:`~facecapges.network.native.power_spectrum`, :func:`~facecapges.network.native.pitch`: what
:meth:`~facecapges.network.audio_features.AudioFeatures.forward_native` runs between torch's FFTs), the sums in
float64; the values equal the torch module's to float32 rounding (``test_matching_predictor``).
"""

from __future__ import annotations

import functools
import importlib
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

N_FFT = 512
HOP = 128
N_MELS = 40
F0_MIN_HZ = 60.0
F0_MAX_HZ = 400.0
VOICED_MIN = 0.3
FEATURE_DIM = N_MELS + 3
AUDIO_REPRS = ("raw", "mel")


def mel_basis_file(sr: int) -> Path:
    """Where Librosa's Mel filter bank for ``sr`` is kept (:func:`mel_basis`)."""
    from importlib import resources

    return Path(str(resources.files("facecapges") / "assets" / f"mel_basis_{sr}_{N_FFT}_{N_MELS}.npy"))


def mel_basis(sr: int) -> np.ndarray:
    """``librosa.filters.mel(sr=sr, n_fft=N_FFT, n_mels=N_MELS)``, (40, 257) float32.

    For the model's rate (16 kHz) it is read from the package's assets, where Librosa wrote
    it (``numpy.save(mel_basis_file(16000), librosa.filters.mel(sr=16000, n_fft=512,
    n_mels=40))``; ``test_recipe`` checks the file still equals Librosa's): importing
    Librosa's filters brings in SciPy's signal package and Numba, ~120 MB that ``live``
    with a style would hold for one matrix. Other rates ask Librosa.
    """
    p = mel_basis_file(sr)
    if p.is_file():
        return np.load(p, allow_pickle=False)
    import librosa

    return librosa.filters.mel(sr=sr, n_fft=N_FFT, n_mels=N_MELS)


def lag_range(sr: float) -> tuple[int, int]:
    """The autocorrelation lags searched for F0 (``F0_MAX_HZ`` … ``F0_MIN_HZ``), both included."""
    return int(math.floor(sr / F0_MAX_HZ)), int(math.ceil(sr / F0_MIN_HZ))


def autocorrelation_length(samples_per_frame: int, lag_max: int) -> int:
    """FFT length of the autocorrelation: any n ≥ S + lag_max leaves lags ≤ lag_max free of wrap-around;
    the smallest 2^k or 3·2^k above it is a fast length (1536 for 1067 samples)."""
    need = samples_per_frame + lag_max
    n = 1 << (need - 1).bit_length()
    return 3 * n // 4 if 3 * n // 4 >= need else n


try:  # NumPy's FFT gufuncs (numpy.fft's own, pinned NumPy 2.4): the call np.fft.rfft / irfft make, without them
    _pfu: Any = importlib.import_module("numpy.fft._pocketfft_umath")
except ImportError:  # pragma: no cover - another NumPy: its public functions
    _pfu = None
_INVERSE_SCALE: dict[tuple[int, str], np.generic] = {}  # (n, dtype) → 1/n in the real dtype, as np.fft.irfft's


def rfft(x: np.ndarray) -> np.ndarray:
    """``np.fft.rfft(x)`` along the last axis, the same bits: its pocketfft gufunc called as ``np.fft.rfft`` calls
    it (norm ``"backward"``: factor 1), without the ~10 µs of its Python layers (a few frames a step: most of the
    call's cost; the plan is pocketfft's own cached one either way)."""
    if _pfu is None or not isinstance(x, np.ndarray):  # pragma: no cover
        return np.fft.rfft(x)
    n, ax = x.shape[-1], x.ndim - 1
    if n < 1:
        return np.fft.rfft(x)  # its error
    out = np.empty(x.shape[:-1] + (n // 2 + 1,), np.result_type(x.dtype, 1j))
    return (_pfu.rfft_n_even if n % 2 == 0 else _pfu.rfft_n_odd)(x, 1, axes=[(ax,), (), (ax,)], out=out)


def irfft(x: np.ndarray, n: int | None = None) -> np.ndarray:
    """``np.fft.irfft(x, n)`` along the last axis, the same bits (:func:`rfft`): the gufunc with ``1/n`` in the
    real dtype, as ``np.fft.irfft``'s backward norm passes it."""
    if _pfu is None or not isinstance(x, np.ndarray):  # pragma: no cover
        return np.fft.irfft(x, n)
    n = (x.shape[-1] - 1) * 2 if n is None else n
    if n < 1:
        return np.fft.irfft(x, n)  # its error
    real = x.real.dtype if x.dtype.kind == "c" else x.dtype
    key = (n, real.char)
    fct = _INVERSE_SCALE.get(key)
    if fct is None:
        real_dtype = np.result_type(real, 1.0)
        fct = _INVERSE_SCALE[key] = np.reciprocal(n, dtype=real_dtype)
    ax = x.ndim - 1
    out = np.empty(x.shape[:-1] + (n,), fct.dtype)
    return _pfu.irfft(x, fct, axes=[(ax,), (), (ax,)], out=out)


@functools.cache
def _scipy_fft():
    """``scipy.fft``, imported on the first batch that needs it and kept (a function-level import of a lazily
    loaded package costs ~5 µs a call)."""
    import scipy.fft

    return scipy.fft


_NUMPY_FFT = SimpleNamespace(rfft=rfft, irfft=irfft)  # numpy.fft's two, as MelFeatures' small batches call them


class MelFeatures:
    """(B, S) frames of samples → (B, 43) log-Mel, energy, log-F0, voicing, in NumPy (module docs).

    The FFTs: NumPy's for small batches (``live``: one stream; SciPy's FFT module is not loaded; its gufuncs called
    directly, :func:`rfft`), SciPy's
    from :attr:`SCIPY_MIN_BATCH` streams (``serve``): the same pocketfft algorithm, vectorised across the
    batch — at 256 streams NumPy's took 7.2 + 2.0 ms a frame for the windows' and the autocorrelation's
    transforms, SciPy's 1.8 + 0.8 (torch's 1.7 + 0.8; one thread, same run). Between them, for every batch,
    the compiled loops of :mod:`facecapges.network.native` (module docs).
    """

    SCIPY_MIN_BATCH = 16

    def __init__(self, sr: int, samples_per_frame: int):
        if samples_per_frame < N_FFT:
            raise ValueError(f"a frame of {samples_per_frame} samples is shorter than the {N_FFT}-sample FFT")
        from facecapges.network import native  # Numba: loaded when features are made, not with this module

        self._mel_energy, self._power, self._pitch = native.mel_energy, native.power_spectrum, native.pitch
        self.mel_t64 = np.ascontiguousarray(mel_basis(sr).astype(np.float32).T, np.float64)  # (257, 40)
        n = np.arange(N_FFT)
        # torch.hann_window(N_FFT, periodic=True), in float32 as the torch module holds it
        self.window = (0.5 - 0.5 * np.cos(2.0 * np.pi * n / N_FFT)).astype(np.float32)
        self.sr = float(sr)
        self.lag_min, self.lag_max = lag_range(self.sr)
        self.n_ac = autocorrelation_length(samples_per_frame, self.lag_max)
        self.n = samples_per_frame
        # the frame's windows as one gather: torch's ``unfold(-1, N_FFT, HOP)`` (center=False)
        self.windows = np.arange((samples_per_frame - N_FFT) // HOP + 1)[:, None] * HOP + np.arange(N_FFT)
        lags = np.arange(self.lag_min, self.lag_max + 1, dtype=np.float32)
        self.log_f0_of_lag = np.log2(np.float32(self.sr) / lags / np.float32(100.0)).astype(np.float32)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, np.float32)
        B, n = x.shape[0], x.shape[-1]
        if n != self.n:
            raise ValueError(f"frames of {n} samples, expected {self.n}")
        out = np.empty((B, FEATURE_DIM), np.float32)
        fft = _scipy_fft() if B >= self.SCIPY_MIN_BATCH else _NUMPY_FFT
        W = len(self.windows)
        # torch's unfold(-1, N_FFT, HOP): a view, no copy (an ndarray over x's buffer: as_strided's result
        # without its Python-level cost)
        frames = np.ndarray((B, W, N_FFT), np.float32, buffer=x, strides=(4 * n, 4 * HOP, 4))
        spec = fft.rfft(frames * self.window)  # (B, 5, 257) complex64
        x0 = np.empty((B, self.n_ac), np.float32)
        self._mel_energy(spec.view(np.float32).reshape(B, W, spec.shape[2], 2), x, self.mel_t64, out, x0)
        f = fft.rfft(x0)
        power = np.empty((B, f.shape[1]), np.float32)
        self._power(f.view(np.float32).reshape(B, f.shape[1], 2), power)
        ac = fft.irfft(power, n=self.n_ac)
        self._pitch(ac, self.lag_min, self.lag_max, self.log_f0_of_lag, np.float32(VOICED_MIN), out)
        return out
