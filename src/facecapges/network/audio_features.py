"""Per-frame audio features: the model's two audio representations (``ModelConfig.audio_repr``).

* ``"raw"`` (thesis table 3.1): a frame's own 16 kHz samples, zero-padded to
  ``samples_per_frame`` = ceil(sr/fps) = 1067, fed to strided convolutions
  (:class:`facecapges.network.network.AudioFrontend`).
* ``"mel"`` (thesis §2.4.1, "Mel spectrum, short-time energy and F0 with Librosa"):
  :class:`AudioFeatures` turns the same 1067 samples into ``FEATURE_DIM`` = 43 numbers:

  ===================== ======================================================================
  0 … 39                log-Mel power spectrum, dB: ``10·log10(max(M, 1e-10))`` of Librosa's
                        Slaney Mel filter bank (``librosa.filters.mel``, 40 bands, 0–8 kHz) over
                        the power spectrogram of 512-sample periodic-Hann windows, hop 128,
                        ``center=False`` — exactly ``librosa.feature.melspectrogram(y=frame,
                        n_fft=512, hop_length=128, center=False)`` — averaged over the
                        frame's 5 windows (power averaged, then dB)
  40                    short-time energy, dB: ``10·log10(mean(x²) + 1e-10)`` over the 1067 samples
  41                    F0 as ``log2(F0 / 100 Hz)``, F0 = sr / the lag (60–400 Hz) of the highest
                        normalised autocorrelation of the frame; 0 when unvoiced
  42                    voicing: that autocorrelation peak (0…1; < 0.3 counts as unvoiced)
  ===================== ======================================================================

Causality and streaming: every feature of frame t is a function of frame t's own
samples only (no look-ahead, no state), so the offline path (a whole clip as (T, S)
frames) and the streaming path (one (1, S) frame per step) call the same
:meth:`AudioFeatures.forward` and get the same values (``test_audio_features``). Librosa's
``power_to_db(top_db=80)`` is *not* used: it clips relative to the maximum of the whole
input, which would make a frame's value depend on the future. The module is pure
torch (``torch.fft``: one call for the frame's five windows, one for the autocorrelation)
so it runs inside the model; its Mel matrix comes from Librosa (stored: :func:`mel_basis`). The streaming kernel's
small batches take :meth:`AudioFeatures.forward_native` instead, a second schedule of
the same computation: the same FFT calls, the work between them in compiled loops
(:mod:`facecapges.network.native`), equal values to float rounding (tested); the naive
loop, training and the offline path run :meth:`AudioFeatures.forward`.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn

from facecapges.network.mel import (  # noqa: F401  (re-exported: the features' constants and filter bank)
    AUDIO_REPRS,
    F0_MAX_HZ,
    F0_MIN_HZ,
    FEATURE_DIM,
    HOP,
    N_FFT,
    N_MELS,
    VOICED_MIN,
    autocorrelation_length,
    lag_range,
    mel_basis,
    mel_basis_file,
)


class AudioFeatures(nn.Module):
    """(…, S) frames of samples → (…, 43) log-Mel, energy, log-F0, voicing (module docs)."""

    mel_basis: torch.Tensor  # (40, 257) buffer
    mel_basis_t: torch.Tensor  # its transpose (257, 40)
    log_f0_of_lag: torch.Tensor  # log2(F0 / 100 Hz) of each autocorrelation lag lag_min … lag_max
    window: torch.Tensor  # (N_FFT,) buffer

    def __init__(self, sr: int, samples_per_frame: int):
        super().__init__()
        if samples_per_frame < N_FFT:
            raise ValueError(f"a frame of {samples_per_frame} samples is shorter than the {N_FFT}-sample FFT")
        mel = mel_basis(sr)  # (40, 257), Slaney scale and norm
        self.register_buffer("mel_basis", torch.from_numpy(mel).float(), persistent=False)
        self.register_buffer("mel_basis_t", self.mel_basis.t().contiguous(), persistent=False)
        self.register_buffer("window", torch.hann_window(N_FFT, periodic=True), persistent=False)
        self.sr = float(sr)
        self.lag_min, self.lag_max = lag_range(self.sr)
        self.n_ac = autocorrelation_length(samples_per_frame, self.lag_max)
        lags = torch.arange(self.lag_min, self.lag_max + 1, dtype=torch.float32)
        self.register_buffer("log_f0_of_lag", torch.log2(self.sr / lags / 100.0), persistent=False)
        self.dim = FEATURE_DIM
        self._native: tuple[np.ndarray, np.ndarray] | None = None  # NumPy copies for forward_native

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        shape = frames.shape[:-1]
        x = frames.reshape(-1, frames.shape[-1]).float()  # (B, S)
        # = torch.stft(x, N_FFT, HOP, window=self.window, center=False): the frame's windows, one FFT call
        spec = torch.fft.rfft(x.unfold(-1, N_FFT, HOP) * self.window)  # (B, n, 257)
        power = (spec * spec.conj()).real.mean(1)  # (B, 257): |X|² averaged over the windows (the Mel map is linear)
        log_mel = torch.log10(torch.matmul(power, self.mel_basis_t).clamp_(min=1e-10)).mul_(10.0)  # (B, 40)
        energy = torch.log10((x * x).mean(-1, keepdim=True).add_(1e-10)).mul_(10.0)  # (B, 1)
        # F0: normalised autocorrelation of the mean-removed frame (zero-padded FFT, no wrap-around)
        x0 = x - x.mean(-1, keepdim=True)
        f = torch.fft.rfft(x0, n=self.n_ac)
        ac = torch.fft.irfft((f * f.conj()).real, n=self.n_ac)[:, : self.lag_max + 1]
        norm = ac[:, self.lag_min :] / ac[:, :1].clamp(min=1e-8)
        peak, idx = norm.max(-1)
        voicing = peak.clamp_(0.0, 1.0)
        log_f0 = torch.where(voicing >= VOICED_MIN, self.log_f0_of_lag[idx], 0.0)  # log2(F0 / 100 Hz), 0 unvoiced
        out = torch.cat([log_mel, energy, log_f0[:, None], voicing[:, None]], -1)
        return out.reshape(shape + (FEATURE_DIM,))

    def forward_native(self, x: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` of (B, S) frames as the streaming kernel's small-batch schedule: the
        same torch FFT calls, and everything between them in three compiled loops
        (:mod:`facecapges.network.native`) instead of ~25 torch calls. Same values to float
        rounding (sums in another order, in float64)."""
        from facecapges.network import native

        if self._native is None:
            self._native = (self.mel_basis_t.double().numpy().copy(), self.log_f0_of_lag.numpy().copy())
        mel_t, log_f0_of_lag = self._native
        B = x.shape[0]
        out = np.empty((B, FEATURE_DIM), np.float32)
        x0 = np.empty((B, self.n_ac), np.float32)
        spec = torch.view_as_real(torch.fft.rfft(x.unfold(-1, N_FFT, HOP) * self.window))  # (B, n, 257, 2)
        native.mel_energy(spec.numpy(), x.numpy(), mel_t, out, x0)
        f = torch.view_as_real(torch.fft.rfft(torch.from_numpy(x0)))
        power = np.empty((B, f.shape[1]), np.float32)
        native.power_spectrum(f.numpy(), power)
        ac = torch.fft.irfft(torch.from_numpy(power), n=self.n_ac).numpy()
        native.pitch(ac, self.lag_min, self.lag_max, log_f0_of_lag, np.float32(VOICED_MIN), out)
        return torch.from_numpy(out)
