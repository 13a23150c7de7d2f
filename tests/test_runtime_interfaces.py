"""Every source, generator and sink of the runtime satisfies its declared protocol (runtime/interfaces.py)."""

from __future__ import annotations

import inspect

import pytest

from facecapges.engine.contract import Stream
from facecapges.runtime import interfaces as I
from facecapges.runtime.inputs import sources as S
from runtime_helpers import checkpoint


def _methods(proto) -> set[str]:
    return {n for n, v in vars(proto).items() if callable(v) and not n.startswith("_")}


def test_file_sources_satisfy_their_protocols(face_video, beat_wav):
    v = S.FileVideo(face_video)
    a = S.FileAudio(beat_wav)
    try:
        assert isinstance(v, I.VideoSource)
        assert isinstance(a, I.AudioSource)
        assert not isinstance(a, I.VideoSource)
    finally:
        v.close()
        a.close()


def test_livelink_is_a_face_feed():
    f = S.LiveLinkFace(0)
    try:
        assert isinstance(f, I.FaceFeed)
    finally:
        f.close()


@pytest.mark.parametrize("cls, proto", [(S.CameraVideo, I.VideoSource), (S.MicAudio, I.AudioSource)])
def test_device_sources_have_the_protocol_methods(cls, proto):
    """Devices cannot open here (no camera, no microphone): their classes must still have every method."""
    for name in _methods(proto):
        got = inspect.signature(getattr(cls, name))
        want = inspect.signature(getattr(proto, name))
        assert list(got.parameters) == list(want.parameters), (cls.__name__, name)


def test_generator_and_sinks(tmp_path):
    from facecapges.runtime.outputs.recorders import BvhRecorder, FaceJsonRecorder, ForFace, MemoryRecorder
    from facecapges.runtime.outputs.viewer import ViewerServer, WebFeed
    from facecapges.runtime.outputs.vmc import VmcSender

    ck = checkpoint()
    assert isinstance(ck.streaming(), Stream)
    sinks = [BvhRecorder(tmp_path / "m.bvh", ck.skeleton, ck.fps), FaceJsonRecorder(tmp_path / "f.json", ck.fps),
             MemoryRecorder(), VmcSender(ck.skeleton, "127.0.0.1", 39539)]
    sinks.append(ForFace(1, sinks[2]))
    server = ViewerServer(b"glb", "127.0.0.1", 0, fps=ck.fps)
    sinks.append(WebFeed(server))
    for s in sinks:
        assert isinstance(s, I.Sink), type(s).__name__
    for s in sinks[:-1]:
        s.close()
