"""The model-rate scheduler: causality, alignment, fallbacks and event counts (real model)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges import timing
from facecapges.arkit import ARKIT_NAMES
from facecapges.runtime.inputs.sources import FaceSample, FileAudio
from facecapges.runtime.scheduler import FaceHold, Scheduler
from runtime_helpers import checkpoint

FPS, SR = 15, 16000


class ScriptedFeed:
    """A face source over given samples; logs what it handed out at which deadline."""

    ended = False
    name = "scripted faces"

    def start(self, t0):
        pass

    def close(self):
        pass

    def __init__(self, samples: list[FaceSample]):
        self.samples = samples
        self.i = 0
        self.log: list[tuple[float, float]] = []  # (deadline, ts handed out)

    def next_face(self, deadline_s):
        due = None
        while self.i < len(self.samples) and self.samples[self.i].ts_s < deadline_s:
            due = self.samples[self.i]
            self.i += 1
        if due is not None:
            self.log.append((deadline_s, due.ts_s))
        return due


class ScriptedAudio:
    """An audio source over an array; logs every request. ``live``: never ends, may starve frames."""

    def __init__(self, samples: np.ndarray, live: bool = False, starve: set[int] = frozenset()):
        self.samples, self.live, self.starve = samples, live, starve
        self.log: list[tuple[int, int]] = []

    name = "scripted audio"

    def start(self, t0):
        pass

    def close(self):
        pass

    def ended_at(self, start):
        return not self.live and start >= len(self.samples)

    def read(self, start, end, now_s=None):
        self.log.append((start, end))
        k = int(round(start * FPS / SR))
        if k in self.starve:
            end = start + (end - start) // 2
        return self.samples[start:min(end, len(self.samples))]


class Recording:
    """Wraps the real generator and keeps the inputs of each step."""

    def __init__(self, gen):
        self.gen, self.inputs = gen, []

    def reset(self, *a, **k):
        self.gen.reset(*a, **k)

    def step(self, audio, face, head):
        self.inputs.append((audio.copy(), face.copy(), head.copy()))
        return self.gen.step(audio, face, head)


def face_track(n_frames: int, seed: int, video_fps: float = 25.0) -> list[FaceSample]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(int(n_frames / FPS * video_fps)):
        R = rot.axis_angle_matrix("Y", np.array(0.3 * np.sin(i / 10)))
        out.append(FaceSample(i / video_fps, rng.uniform(0, 1, 52).astype(np.float32),
                              rot.matrix_to_rot6d(R).astype(np.float32), True))
    return out


def speech(n_frames: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(n_frames / FPS * SR)) / SR
    return (0.3 * np.sin(2 * np.pi * 180 * t) * (1 + np.sin(2 * np.pi * 3 * t)) + 0.01 * rng.normal(size=t.size)
            ).astype(np.float32)


def run(feed, audio, n=None, **kw):
    ck = checkpoint()
    gen = Recording(ck.streaming())
    s = Scheduler(gen, fps=FPS, sr=SR, face_feed=feed, audio=audio, **kw)
    outs = []
    s.run(max_frames=n, on_frame=outs.append)
    return s, gen, outs


def test_never_reads_future_input():
    N = 45
    feed, audio = ScriptedFeed(face_track(N, 0)), ScriptedAudio(speech(N, 0))
    s, gen, outs = run(feed, audio)
    assert s.frames == len(outs) == N  # ends with the audio: ceil(duration · fps)
    for k, (start, end) in enumerate(audio.log):
        s_k, e_k = timing.frame_sample_bounds(k, FPS, SR)
        assert (start, end) == (s_k, e_k)  # exactly the samples frame k owns
    for deadline, ts in feed.log:
        assert ts < deadline
    # frame k used the newest face sample stamped before (k+1)/fps
    for k, (_, face, _) in enumerate(gen.inputs):
        newest = max((x for x in feed.samples if x.ts_s < (k + 1) / FPS), key=lambda x: x.ts_s)
        np.testing.assert_array_equal(face, newest.weights52)


def test_future_inputs_do_not_change_past_outputs():
    N, K = 40, 25
    track_a, audio_a = face_track(N, 1), speech(N, 1)
    track_b = [x if x.ts_s < K / FPS else FaceSample(x.ts_s, 1 - x.weights52, x.head_rot6d[::-1].copy(), True)
               for x in track_a]
    audio_b = audio_a.copy()
    s_K = int(timing.frame_sample_bounds(K, FPS, SR)[0])
    audio_b[s_K:] = np.random.default_rng(9).normal(size=audio_b.size - s_K).astype(np.float32)
    _, _, outs_a = run(ScriptedFeed(track_a), ScriptedAudio(audio_a))
    _, _, outs_b = run(ScriptedFeed(track_b), ScriptedAudio(audio_b))
    for k in range(K):
        np.testing.assert_array_equal(outs_a[k].pose, outs_b[k].pose)
        np.testing.assert_array_equal(outs_a[k].face, outs_b[k].face)
    assert not np.array_equal(outs_a[K].face, outs_b[K].face)


def test_feed_stops_hold_then_ease_without_jumps():
    N, stop = 60, 20
    track = [x for x in face_track(N, 2) if x.ts_s < stop / FPS]
    s, gen, outs = run(ScriptedFeed(track), ScriptedAudio(speech(N, 2)))
    last = track[-1]
    faces = np.stack([o.face for o in outs])
    held = [k for k in range(stop, N) if (k + 1) / FPS - last.ts_s <= 0.5]
    for k in held:  # held unchanged for 500 ms
        np.testing.assert_array_equal(faces[k], last.weights52)
        assert outs[k].face_found
    eased = [k for k in range(stop, N) if (k + 1) / FPS - last.ts_s >= 1.5]
    model_faces = np.stack([f for _, f, _ in gen.inputs])
    assert eased and np.abs(model_faces[eased]).max() == 0.0  # the model's input: neutral after hold + ease
    # what the avatar shows: nothing of the old face, the mouth moved by the speech alone
    from facecapges.capture.speech_mouth import MOUTH_NAMES

    mouth = [ARKIT_NAMES.index(n) for n in MOUTH_NAMES]
    rest = np.setdiff1d(np.arange(52), mouth)
    assert np.abs(faces[eased][:, rest]).max() == 0.0
    jaw = faces[eased, ARKIT_NAMES.index("jawOpen")]
    assert jaw.max() > 0.1 and np.ptp(jaw) > 0.02
    for k in eased:  # the head faces the camera again
        np.testing.assert_allclose(outs[k].head, rot.identity_rot6d(), atol=1e-6)
    assert np.abs(np.diff(model_faces[stop - 1:], axis=0)).max() < 0.25  # eased, no jump
    assert s.events["input_frames_reused"] == N - stop
    lost = N - stop - len(held)
    assert s.events["face_lost_frames"] == lost and s.events["face_lost_events"] == 1
    assert np.isfinite(np.stack([o.pose for o in outs])).all()


def test_audio_underrun_is_zero_filled_and_counted():
    N = 20
    audio = ScriptedAudio(speech(N, 3), live=True, starve={10, 11, 12})
    s, gen, _outs = run(ScriptedFeed(face_track(N, 3)), audio, n=N)
    assert s.events["audio_underruns"] == 3
    for k in range(N):
        a = gen.inputs[k][0]
        s_k, e_k = timing.frame_sample_bounds(k, FPS, SR)
        assert a.shape == (e_k - s_k,)
        if k in (10, 11, 12):
            half = (e_k - s_k) // 2
            np.testing.assert_array_equal(a[:half], audio.samples[s_k:s_k + half])
            assert not a[half:].any()
        else:
            np.testing.assert_array_equal(a, audio.samples[s_k:e_k])


def test_no_face_source_gives_neutral_face_and_silence_gives_zeros():
    s, gen, _outs = run(None, None, n=5)
    for audio, face, head in gen.inputs:
        assert not audio.any() and not face.any()
        np.testing.assert_array_equal(head, rot.identity_rot6d())
    assert s.events["face_lost_frames"] == 5


def test_report_has_every_stage():
    s, _, _ = run(ScriptedFeed(face_track(12, 4)), ScriptedAudio(speech(12, 4)))
    rep = s.report(warmup=2)
    assert rep["frames"] == 12
    for stage in ("capture", "features", "model", "output", "total"):
        assert set(rep["latency_ms"][stage]) >= {"p50", "p99"}
        assert rep["latency_ms"][stage]["p50"] >= 0
    assert rep["latency_ms"]["total"]["p50"] >= rep["latency_ms"]["model"]["p50"]


def test_realtime_file_audio_is_paced(tmp_path):
    from facecapges.io.audio import save_audio

    wav = save_audio(tmp_path / "a.wav", speech(30, 5))
    fa = FileAudio(wav, realtime=True)
    assert len(fa.read(0, 16000, now_s=0.25)) == 4000  # only what "exists" by then
    assert len(FileAudio(wav).read(0, 16000, now_s=0.25)) == 16000  # offline: all of it at once
    t0 = time.monotonic()
    s, _gen, outs = run(ScriptedFeed(face_track(8, 5)), fa, n=8, realtime=True)
    assert len(outs) == 8 and s.events["audio_underruns"] == 0
    assert time.monotonic() - t0 >= 8 / FPS - 0.02  # frame k waits for its deadline


def test_face_hold_unit():
    h = FaceHold(hold_ms=500, ease_ms=1000)
    w = np.full(52, 0.8, np.float32)
    R = rot.axis_angle_matrix("Y", np.array(0.6))
    h.fresh(FaceSample(1.0, w, rot.matrix_to_rot6d(R).astype(np.float32)))
    wf, _hf, found = h.stale(1.4)  # within the 500 ms hold
    np.testing.assert_array_equal(wf, w)
    assert found
    wm, hm, found = h.stale(2.0)  # half-way through the ease: smoothstep(0.5) = 0.5
    assert not found and wm[ARKIT_NAMES.index("jawOpen")] == pytest.approx(0.4)
    ang = rot.geodesic_angle(np.eye(3), rot.rot6d_to_matrix(hm.astype(np.float64)))
    assert ang == pytest.approx(0.3, abs=1e-6)
    wz, hz, _ = h.stale(2.6)
    assert not wz.any()
    np.testing.assert_allclose(hz, rot.identity_rot6d(), atol=1e-7)


def test_head_driver_converts_the_head_and_the_spine_in_one_call_with_the_same_bits():
    """While tracked, ``HeadDriver`` converts the captured head and the pose's Spine in one ``rot6d_to_matrix`` call
    (issue 36): the same pose, to the bit, as converting each on its own (``set_head`` with the head's matrix)."""
    from facecapges.runtime.head import HeadDriver, set_head

    rng = np.random.default_rng(5)
    drv = HeadDriver("capture")
    for k in range(50):
        pose = rng.normal(size=(47, 6)).astype(np.float32)
        head = rng.normal(size=6).astype(np.float32)
        shown = drv(pose, head, True, k / 15)
        R = rot.rot6d_to_matrix(head.astype(np.float64))
        assert shown.tobytes() == set_head(pose, R).tobytes()
        assert drv._R.tobytes() == R.tobytes()
