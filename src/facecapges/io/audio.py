"""Audio in and out: any file → mono float32 at 16 kHz, and back to WAV.

Conventions
-----------
* Audio inside the project is a 1-D ``numpy.float32`` array in [-1, 1] at
  ``sr`` = :data:`~facecapges.timing.AUDIO_SR` (16 000 Hz) unless a function says
  otherwise. Multi-channel files are mixed down by the mean of their channels.
* Files libsndfile reads (WAV, FLAC, OGG, …) are decoded by ``soundfile`` and, when
  their rate differs, resampled with soxr's high-quality filter (through
  ``librosa.resample(res_type="soxr_hq")``).
* Audio tracks of video and compressed containers (``.mp4``, ``.avi``, ``.mov``,
  ``.mkv``, ``.webm``, ``.m4a``, ``.aac``, ``.mp3``) are decoded by the ffmpeg binary
  that ships with ``imageio-ffmpeg``, straight to mono float32 at ``sr`` on a pipe (no
  temporary file; ffmpeg's own resampler does the rate change).
* A RIFF/WAV file whose ``data`` chunk is shorter than its header declares is
  *truncated*: libsndfile would silently return the part that is there, so
  :func:`load_audio` checks the chunk sizes itself and refuses such a file.

* Long files can be read block by block (:func:`audio_blocks`, :func:`audio_level`),
  so memory stays flat in the length of the input: soxr's streaming resampler for
  libsndfile formats, ffmpeg's pipe read in pieces for the others.

Every problem a user can fix (missing, truncated, undecodable, empty file, a video
without sound) raises :class:`~facecapges.errors.UserError` naming the file.
"""

from __future__ import annotations

import math
import struct
import subprocess
from pathlib import Path

import numpy as np
import soundfile as sf

from facecapges.errors import file_error, require_file
from facecapges.timing import AUDIO_SR

#: Suffixes decoded with ffmpeg instead of libsndfile.
FFMPEG_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4a", ".aac", ".mp3", ".m4v"})

#: Default threshold of :func:`is_silent`: RMS below -50 dBFS counts as silence.
SILENCE_DB = -50.0


def _riff_truncation(path: Path) -> str | None:
    """Describe how a RIFF/WAV file is truncated, or None when it is complete (or not RIFF)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] not in (b"RIFF", b"RIFX") or head[8:12] != b"WAVE":
            return None
        fmt = "<I" if head[:4] == b"RIFF" else ">I"
        pos = 12
        while pos + 8 <= size:
            f.seek(pos)
            chunk = f.read(8)
            cid, csize = chunk[:4], struct.unpack(fmt, chunk[4:])[0]
            if cid == b"data":
                if csize in (0, 0xFFFFFFFF):  # streaming writers leave the size open
                    return None
                have = size - pos - 8
                if have < csize:
                    return f"truncated WAV: data chunk declares {csize} bytes, file holds {have}"
                return None
            pos += 8 + csize + (csize & 1)
        return "truncated WAV: no complete 'data' chunk"


def _ffmpeg_pcm_cmd(path: Path, sr: int) -> list[str]:
    """ffmpeg decoding ``path``'s audio to mono float32 little-endian PCM at ``sr`` on stdout."""
    import imageio_ffmpeg

    return [imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-v", "error", "-i", str(path), "-vn", "-ac", "1",
            "-ar", str(sr), "-f", "f32le", "-acodec", "pcm_f32le", "pipe:1"]  # fmt: skip


def _decode_ffmpeg(path: Path, sr: int) -> np.ndarray:
    cmd = _ffmpeg_pcm_cmd(path, sr)
    proc = subprocess.run(cmd, capture_output=True, check=False)
    err = proc.stderr.decode("utf-8", "replace").strip()
    if proc.returncode != 0:
        last = err.splitlines()[-1] if err else f"ffmpeg exit status {proc.returncode}"
        if "does not contain any stream" in err or "matches no streams" in err:
            raise file_error(path, "has no audio track")
        raise file_error(path, f"cannot decode audio ({last})")
    if not proc.stdout:
        raise file_error(path, "has no audio track" if not err else f"cannot decode audio ({err.splitlines()[-1]})")
    return np.frombuffer(proc.stdout, dtype="<f4").astype(np.float32)


def resample_audio(audio: np.ndarray, sr_in: int, sr_out: int = AUDIO_SR) -> np.ndarray:
    """Resample mono ``audio`` from ``sr_in`` to ``sr_out`` Hz (soxr high quality), float32."""
    audio = np.asarray(audio, dtype=np.float32)
    if sr_in == sr_out:
        return audio
    import librosa

    return librosa.resample(audio, orig_sr=sr_in, target_sr=sr_out, res_type="soxr_hq").astype(np.float32)


def load_audio(path: str | Path, sr: int = AUDIO_SR) -> np.ndarray:
    """Read any audio file (or a video's audio track) as mono float32 at ``sr`` Hz, shape (S,).

    >>> audio = load_audio("speech.wav")      # doctest: +SKIP
    >>> audio.shape, audio.dtype               # doctest: +SKIP
    ((1025536,), dtype('float32'))
    """
    path = require_file(path, "audio file")
    if path.stat().st_size == 0:
        raise file_error(path, "audio file is empty (0 bytes)")
    if path.suffix.lower() in FFMPEG_SUFFIXES:
        audio = _decode_ffmpeg(path, sr)
    else:
        problem = _riff_truncation(path)
        if problem:
            raise file_error(path, problem)
        try:
            data, file_sr = sf.read(str(path), dtype="float32", always_2d=True)
        except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
            reason = str(exc).split(":", 1)[-1].strip() or "unreadable"
            raise file_error(path, f"not a readable audio file ({reason})") from None
        audio = resample_audio(data.mean(axis=1), int(file_sr), sr)
    if audio.size == 0:
        raise file_error(path, "audio file holds no samples")
    if not np.isfinite(audio).all():
        raise file_error(path, "audio contains NaN or infinite samples")
    return np.ascontiguousarray(audio, dtype=np.float32)


def check_audio(path: str | Path) -> Path:
    """Check that ``path`` is audio we can decode, cheaply (header, or ffmpeg on the first second).

    For commands that use the audio only at their end (``render --audio``): the file is
    refused before the work, with the message :func:`load_audio` would give.
    """
    path = require_file(path, "audio file")
    if path.stat().st_size == 0:
        raise file_error(path, "audio file is empty (0 bytes)")
    if path.suffix.lower() in FFMPEG_SUFFIXES:
        import imageio_ffmpeg

        cmd = [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-nostdin",
            "-v",
            "error",
            "-t",
            "1",
            "-i",
            str(path),
            "-vn",
            "-ac",
            "1",
            "-f",
            "f32le",
            "-acodec",
            "pcm_f32le",
            "pipe:1",
        ]
        proc = subprocess.run(cmd, capture_output=True, check=False)
        err = proc.stderr.decode("utf-8", "replace").strip()
        if proc.returncode != 0 or not proc.stdout:
            if not err or "does not contain any stream" in err or "matches no streams" in err:
                raise file_error(path, "has no audio track")
            raise file_error(path, f"cannot decode audio ({err.splitlines()[-1]})")
        return path
    problem = _riff_truncation(path)
    if problem:
        raise file_error(path, problem)
    try:
        info = sf.info(str(path))
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        reason = str(exc).split(":", 1)[-1].strip() or "unreadable"
        raise file_error(path, f"not a readable audio file ({reason})") from None
    if info.frames == 0:
        raise file_error(path, "audio file holds no samples")
    return path


BLOCK_SECONDS = 30.0  # seconds of audio per block of the streaming readers


def _check_readable(path: Path) -> sf.SoundFile | None:
    """The open SoundFile of a libsndfile format (None for ffmpeg formats); UserError when unreadable."""
    path = require_file(path, "audio file")
    if path.stat().st_size == 0:
        raise file_error(path, "audio file is empty (0 bytes)")
    if path.suffix.lower() in FFMPEG_SUFFIXES:
        return None
    problem = _riff_truncation(path)
    if problem:
        raise file_error(path, problem)
    try:
        return sf.SoundFile(str(path))
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        reason = str(exc).split(":", 1)[-1].strip() or "unreadable"
        raise file_error(path, f"not a readable audio file ({reason})") from None


def _native_blocks(path: Path, sr: int | None, block_s: float):
    """(rate, iterator of mono float32 blocks): at the file's own rate when ``sr`` is None."""
    f = _check_readable(path)
    if f is None:  # ffmpeg decodes (and resamples) onto a pipe we read in pieces
        rate = sr or AUDIO_SR
        cmd = _ffmpeg_pcm_cmd(path, rate)

        def gen():
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            try:
                n = int(block_s * rate) * 4
                while chunk := proc.stdout.read(n):
                    yield np.frombuffer(chunk[: len(chunk) // 4 * 4], dtype="<f4").astype(np.float32)
                err = proc.stderr.read().decode("utf-8", "replace").strip()
                if proc.wait() != 0:
                    if "does not contain any stream" in err or "matches no streams" in err:
                        raise file_error(path, "has no audio track")
                    raise file_error(path, f"cannot decode audio ({(err.splitlines() or ['ffmpeg failed'])[-1]})")
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()

        return rate, gen()

    def gen_sf():
        with f:
            for block in f.blocks(blocksize=max(1, int(block_s * f.samplerate)), dtype="float32", always_2d=True):
                yield block.mean(axis=1)

    return f.samplerate, gen_sf()


def audio_blocks(path: str | Path, sr: int = AUDIO_SR, block_s: float = BLOCK_SECONDS):
    """Mono float32 blocks of ``path`` at ``sr`` Hz, decoded and resampled piece by piece.

    The same samples as :func:`load_audio` (soxr high quality, streaming), with memory
    that does not grow with the file's length.
    """
    path = Path(path)
    rate, blocks = _native_blocks(path, sr, block_s)
    if rate == sr:
        yield from blocks
        return
    import soxr

    rs = soxr.ResampleStream(rate, sr, 1, dtype="float32", quality="HQ")
    for block in blocks:
        yield rs.resample_chunk(block)
    yield rs.resample_chunk(np.zeros(0, np.float32), last=True)


def audio_level(path: str | Path, block_s: float = BLOCK_SECONDS) -> tuple[float, float]:
    """(duration in s, RMS level in dBFS) of a file, read block by block at its own rate (no resampling).

    For refusing silent input before any work: memory is flat in the file's length.
    """
    path = Path(path)
    rate, blocks = _native_blocks(path, None, block_s)
    n, energy = 0, 0.0
    for block in blocks:
        if not np.isfinite(block).all():
            raise file_error(path, "audio contains NaN or infinite samples")
        n += len(block)
        energy += float(np.dot(block.astype(np.float64), block.astype(np.float64)))
    if n == 0:
        raise file_error(path, "audio file holds no samples")
    rms = math.sqrt(energy / n)
    return n / rate, (20.0 * math.log10(rms) if rms > 0 else float("-inf"))


def save_audio(path: str | Path, audio: np.ndarray, sr: int = AUDIO_SR, subtype: str = "PCM_16") -> Path:
    """Write mono ``audio`` (S,) as a WAV file (16-bit PCM by default), atomically. Returns the path.

    Samples are clipped to [-1, 1] for integer subtypes.
    """
    audio = np.asarray(audio, dtype=np.float32)
    if audio.ndim != 1:
        raise ValueError(f"audio must be mono (S,), got shape {audio.shape}")
    if subtype.startswith("PCM"):
        audio = np.clip(audio, -1.0, 1.0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    sf.write(str(tmp), audio, sr, subtype=subtype, format="WAV")
    tmp.replace(path)
    return path


def rms_db(audio: np.ndarray) -> float:
    """Root-mean-square level of ``audio`` in dBFS (−inf for all zeros)."""
    audio = np.asarray(audio, dtype=np.float64)
    if audio.size == 0:
        return float("-inf")
    rms = float(np.sqrt(np.mean(audio**2)))
    return 20.0 * np.log10(rms) if rms > 0 else float("-inf")


def is_silent(audio: np.ndarray, threshold_db: float = SILENCE_DB) -> bool:
    """True when ``audio``'s RMS level is below ``threshold_db`` dBFS (default −50)."""
    return rms_db(audio) < threshold_db
