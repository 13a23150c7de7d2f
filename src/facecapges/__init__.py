"""FaceCapGes: real-time co-speech gestures from face, head pose and speech.

The Python API (README "Python API")::

    style = facecapges.load_style()             # the default style; style="beat2-scott-demo" for the network
    stream = style.streaming()                  # a Stream: one live stream (either engine)
    pose = stream.step(audio_chunk, face, head) # (47, 6) rot6d, frame by frame

The names below are imported on first use, so ``import facecapges`` stays light (no
torch until a checkpoint is loaded).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_EXPORTS: dict[str, str] = {
    "load_style": "facecapges.styles",
    "list_styles": "facecapges.styles",
    "NetworkStyle": "facecapges.network.style",
    "MatchingStyle": "facecapges.matching.style",
    "load_style_or_file": "facecapges.styles",
    "DEFAULT_STYLE": "facecapges.styles",
    "GestureEngine": "facecapges.engine.contract",
    "Stream": "facecapges.engine.contract",
    "BatchedStreams": "facecapges.engine.contract",
    "load_audio": "facecapges.io.audio",
    "UserError": "facecapges.errors",
    "MODEL_FPS": "facecapges.timing",
    "AUDIO_SR": "facecapges.timing",
    "ARKIT_NAMES": "facecapges.arkit",
    "N_BLENDSHAPES": "facecapges.arkit",
    "UPPER_BODY": "facecapges.skeleton",
    "N_JOINTS": "facecapges.skeleton",
}

__all__ = [  # the API first, then the conventions
    "ARKIT_NAMES",
    "AUDIO_SR",
    "DEFAULT_STYLE",
    "MODEL_FPS",
    "N_BLENDSHAPES",
    "N_JOINTS",
    "UPPER_BODY",
    "BatchedStreams",
    "GestureEngine",
    "MatchingStyle",
    "NetworkStyle",
    "Stream",
    "UserError",
    "__version__",
    "list_styles",
    "load_audio",
    "load_style",
    "load_style_or_file",
]
assert set(__all__) == {"__version__", *_EXPORTS}

if TYPE_CHECKING:
    from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES
    from facecapges.engine.contract import BatchedStreams, GestureEngine, Stream
    from facecapges.errors import UserError
    from facecapges.io.audio import load_audio
    from facecapges.matching.style import MatchingStyle
    from facecapges.network.style import NetworkStyle
    from facecapges.skeleton import N_JOINTS, UPPER_BODY
    from facecapges.styles import DEFAULT_STYLE, list_styles, load_style, load_style_or_file
    from facecapges.timing import AUDIO_SR, MODEL_FPS


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'facecapges' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
