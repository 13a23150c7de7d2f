"""Small study material cut from the real shared BEAT clip, written into a test's tmp_path.

Clips: ``n_clips`` pieces of ``seconds`` s of 2_scott_0_1_1 (BVH at 15 fps + the matching
16 kHz audio slice + a face track whose jaw follows the slice's loudness). Systems:
``ground_truth`` (the aligned motion) and copies of the motion taken ``shift`` frames
later ("time-shifted systems"): same length, same skeleton, different motion.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from facecapges.arkit import ARKIT_NAMES
from facecapges.io.audio import load_audio, save_audio
from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.io.face_json import write_face_json

SYSTEMS = ("ground_truth", "shift_4s", "shift_9s")
SHIFTS = (0, 60, 135)  # frames at 15 fps


def make_clips(tmp: Path, beat_bvh: Path, beat_wav: Path, n_clips: int = 3, seconds: float = 2.0,
               systems: tuple[str, ...] = SYSTEMS, face_fps: float = 30.0) -> Path:
    """Write the media and CLIPS.yaml under ``tmp``; returns the YAML path."""
    bvh = read_bvh(beat_bvh)
    audio = load_audio(beat_wav)
    fps = bvh.fps
    n = int(round(seconds * fps))
    media = tmp / "media"
    media.mkdir(parents=True, exist_ok=True)
    clips = []
    for c in range(n_clips):
        start = 90 + c * 200
        cid = f"clip{c + 1}"
        a = audio[int(start / fps * 16000): int((start + n) / fps * 16000)]
        save_audio(media / f"{cid}.wav", a)
        nf = int(round(len(a) / 16000 * face_fps))
        hop = len(a) / nf
        rms = np.array([np.sqrt(np.mean(a[int(i * hop): int((i + 1) * hop)] ** 2)) for i in range(nf)])
        w = np.zeros((nf, len(ARKIT_NAMES)))
        w[:, ARKIT_NAMES.index("jawOpen")] = np.clip(rms / (rms.max() + 1e-9), 0, 1) * 0.6
        w[:, ARKIT_NAMES.index("eyeBlinkLeft")] = w[:, ARKIT_NAMES.index("eyeBlinkRight")] = \
            (np.arange(nf) % int(face_fps * 1.5) < 3).astype(float)
        write_face_json(media / f"{cid}.json", w, face_fps, layout="full")  # the track at its own rate
        entry = {"id": cid, "audio": f"media/{cid}.wav", "face": f"media/{cid}.json", "bvh": {}}
        for s, shift in zip(systems, SHIFTS * 3):
            write_bvh(media / f"{cid}-{s}.bvh", bvh.skeleton, bvh.motion[start + shift: start + shift + n], fps)
            entry["bvh"][s] = f"media/{cid}-{s}.bvh"
        clips.append(entry)
    path = tmp / "CLIPS.yaml"
    path.write_text(yaml.safe_dump({"systems": list(systems), "clips": clips}, sort_keys=False), encoding="utf-8")
    return path
