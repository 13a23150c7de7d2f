"""30/60 Hz output between 15 fps model frames: the blend itself, the emitting thread, and the viewer at --rate."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.outputs.upsample import Upsampler, added_latency_s, blend_frames, substeps


def frame(k: int, arm_deg: float, jaw: float, head_yaw_deg: float = 0.0) -> OutputFrame:
    q = np.tile([1.0, 0.0, 0.0, 0.0], (47, 1))
    q[4] = rot.matrix_to_quaternion(rot.axis_angle_matrix("Z", np.array(np.radians(arm_deg))))
    face = np.zeros(52, np.float32)
    face[24] = jaw
    head = rot.matrix_to_rot6d(rot.axis_angle_matrix("Y", np.array(np.radians(head_yaw_deg))))
    return OutputFrame(k, k / 15, rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)), q, face, head, True, {"total": 1.0})


def test_rates_and_latency():
    assert substeps(15, 15) == 1 and substeps(30, 15) == 2 and substeps(60, 15) == 4
    for bad in (20, 25, 7.5, 0, -30):
        with pytest.raises(ValueError):
            substeps(bad, 15)
    assert added_latency_s(30, 15) * 1000 == pytest.approx(33.333, abs=1e-3)
    assert added_latency_s(60, 15) * 1000 == pytest.approx(50.0)
    assert added_latency_s(15, 15) == 0


def test_blend_slerps_rotations_and_lerps_weights():
    a, b = frame(0, 0.0, 0.2, 0.0), frame(1, 80.0, 0.6, 40.0)
    m = blend_frames(a, b, 0.25)
    angle = np.degrees(2 * np.arccos(np.clip(m.quats[4, 0], -1, 1)))
    assert angle == pytest.approx(20.0, abs=1e-3)  # slerp: a quarter of the arc
    assert m.face[24] == pytest.approx(0.3) and m.time_s == pytest.approx(0.25 / 15)
    R = rot.rot6d_to_matrix(m.head.astype(np.float64))
    assert np.degrees(np.arctan2(R[0, 2], R[2, 2])) == pytest.approx(10.0, abs=1e-3)
    np.testing.assert_allclose(rot.rot6d_to_matrix(m.pose.astype(np.float64)), rot.quaternion_to_matrix(m.quats),
                               atol=1e-5)
    assert blend_frames(a, b, 1.0) is b


class Collect:
    def __init__(self):
        self.frames, self.closed = [], False

    def write(self, fr):
        self.frames.append((time.monotonic(), fr))

    def close(self):
        self.closed = True


def wait_emitted(up: Upsampler, n: int, timeout: float = 10.0) -> None:
    deadline = time.time() + timeout
    while up.emitted < n and time.time() < deadline:
        time.sleep(0.002)


def feed(up: Upsampler, frames, period: float = 1 / 15) -> None:
    """Write ``frames`` one model period apart (on an absolute schedule)."""
    t0 = time.monotonic()
    for k, fr in enumerate(frames):
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
        up.write(fr)


@pytest.mark.serial
def test_upsampler_sends_on_its_clock_and_ends_on_the_last():
    sink = Collect()
    up = Upsampler([sink], fps=15, rate_hz=30)
    feed(up, [frame(k, 10.0 * k, 0.1 * k) for k in range(6)])
    time.sleep(0.2)  # the model stops: the latest pose is held, still at 30 Hz
    up.close()
    assert sink.closed
    stamps = np.array([t for t, _ in sink.frames])
    times = [f.time_s for _, f in sink.frames]
    span = stamps[-1] - stamps[0]
    assert abs(len(stamps) - 1 - span * 30) <= 2  # one frame every 1/30 s from the first model frame on
    assert np.all(np.diff(times) >= 0)  # the stream time never goes back
    assert sink.frames[-1][1].face[24] == pytest.approx(0.5)
    arm = [np.degrees(2 * np.arccos(np.clip(f.quats[4, 0], -1, 1))) for _, f in sink.frames]
    assert np.all(np.diff(arm) > -1e-3) and arm[-1] == pytest.approx(50, abs=1e-3)
    assert len({round(a, 3) for a in arm}) > 8  # in-betweens, not a 15 Hz staircase


def test_a_frame_that_comes_early_starts_from_what_was_shown():
    sink = Collect()
    up = Upsampler([sink], fps=15, rate_hz=60)
    up.write(frame(0, 0.0, 0.0))
    wait_emitted(up, 1)
    up.write(frame(1, 40.0, 0.4))
    wait_emitted(up, 3)  # in-betweens are out …
    up.write(frame(2, 80.0, 0.8))  # … and frame 2 arrives early
    wait_emitted(up, 10)
    up.close()
    arm = [np.degrees(2 * np.arccos(np.clip(f.quats[4, 0], -1, 1))) for _, f in sink.frames]
    assert arm[0] == pytest.approx(0) and arm[-1] == pytest.approx(80, abs=1e-3)
    assert np.all(np.diff(arm) > -1e-3)  # no jump back: the new segment starts where the avatar was


@pytest.mark.serial
def test_an_idle_model_still_gets_the_rate():
    """One model frame and then nothing (an idle or stalled generator): the pose goes out at the rate anyway."""
    sink = Collect()
    up = Upsampler([sink], fps=15, rate_hz=60)
    up.write(frame(0, 30.0, 0.2))
    time.sleep(0.5)
    up.close()
    assert 25 <= len(sink.frames) <= 33 and all(f.face[24] == pytest.approx(0.2) for _, f in sink.frames)


def _viewer_feed(url: str, n: int) -> tuple[dict | None, list[float]]:
    """The viewer at ``url`` (``http://…/``) over its WebSocket: its ``rate`` message (None if it sends none before
    the first pose) and the stream times of its first ``n`` poses."""
    from websockets.sync.client import connect

    from facecapges.runtime.outputs import protocol

    with connect(url.replace("http://", "ws://") + "ws", max_size=None) as ws:
        assert json.loads(ws.recv(timeout=30))["type"] == "hello"
        rate, times = None, []
        while len(times) < n:
            msg = ws.recv(timeout=30)
            kind = json.loads(msg)["type"]
            if kind == "rate" and not times:
                rate = json.loads(msg)
            elif kind == "pose":
                times.append(protocol.decode_pose(msg)["time"])
    return rate, times


@pytest.mark.serial
def test_viewer_gets_the_model_frames_and_vmc_30_a_second(face_video):
    """``live --web … --vmc … --rate 30``: VMC gets 30 Hz with its stream time strictly increasing; the viewer's
    feed the model's frames (15 a second on their own times: one encode and send a frame, issue 36) after a
    ``rate`` message telling the page to blend between them itself (viewer.py)."""
    from pythonosc.osc_bundle import OscBundle

    from runtime_helpers import cli_popen, vmc_frames, wait_line

    vmc_times = []

    def got(d: bytes, _: float) -> None:
        vmc_times.extend(float(m.params[0]) for m in OscBundle(d) if m.address == "/VMC/Ext/T")

    with vmc_frames(got) as (host, port):
        proc = cli_popen("live", "--video", str(face_video), "--realtime", "--loop", "--web", "127.0.0.1:0",
                         "--vmc", f"{host}:{port}", "--rate", "30", "--max-seconds", "60")
        try:
            line = wait_line(proc, "viewer: ")
            assert line, proc.stderr.read()[-2000:]
            rate, times = _viewer_feed(line.split()[1], 30)
        finally:
            proc.kill()
            proc.wait()
    assert rate == {"type": "rate", "fps": 15.0, "rate": 30.0}
    steps = np.diff(times) * 15
    assert np.all(steps > 0) and np.median(steps) == pytest.approx(1.0, abs=0.05)  # the model's frames …
    assert np.abs(np.array(times) * 15 - np.round(np.array(times) * 15)).max() < 1e-3  # … on their own times
    vmc = np.diff(vmc_times) * 30
    assert len(vmc) > 30 and np.all(vmc > 0) and np.median(vmc) == pytest.approx(1.0, abs=0.05)


@pytest.mark.serial
@pytest.mark.slow
def test_viewer_page_blends_between_model_frames(face_video):
    """``live --web --rate 30`` in headless Chromium: the page draws blends between the feed's frames (on the
    display's clock; headless Chromium draws only a few frames a second), and its blend is the slerp the short
    way round and the weights' lerp."""
    from runtime_helpers import cli_popen, wait_line

    proc = cli_popen("live", "--video", str(face_video), "--realtime", "--loop", "--web", "127.0.0.1:0",
                     "--rate", "30", "--max-seconds", "120")
    try:
        line = wait_line(proc, "viewer: ")
        assert line, proc.stderr.read()[-2000:]
        state, png, half = _page_blends(line.split()[1])
        Path("/tmp/facecapges-viewer-blends.png").write_bytes(png)  # for a human look
    finally:
        proc.kill()
        proc.wait()
    assert state and state["errors"] == [] and state["rate"] == 30, state
    assert state["blends"] >= 5, state  # in-betweens drawn
    # a quarter of a 90° turn about Z is 22.5°, the shorter way round (−q is the same rotation); weights linearly
    assert half["pose"] == pytest.approx([np.cos(np.pi / 16), 0, 0, np.sin(np.pi / 16)], abs=1e-9)
    assert half["weights"] == pytest.approx([0.25, 0.75])


def _page_blends(url: str) -> tuple[dict | None, bytes, dict]:
    """The viewer page at ``url``: its state once it drew 30 frames, a screenshot, and its own blend of two frames."""
    import base64

    from facecapges.avatar.render.browser import Browser
    from runtime_helpers import _wait_state

    with Browser({}, "/", width=640, height=480, timeout=90) as b:
        b.call("Page.navigate", url=url)
        state = _wait_state(b, lambda s: s["ready"] and s["drawn"] >= 30, 90)
        png = base64.b64decode(b.call("Page.captureScreenshot", format="png")["data"])
        half = b.evaluate("(() => { const c = Math.SQRT1_2, r = window.facecapgesViewer.between("
                          "{pose: [1, 0, 0, 0], weights: [0, 1]}, {pose: [-c, 0, 0, -c], weights: [1, 0]}, 0.25);"
                          " return {pose: Array.from(r.pose), weights: Array.from(r.weights)}; })()")
    return state, png, half
