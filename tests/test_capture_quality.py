"""The calibration-free face estimator against MediaPipe's learned blendshapes on a real talking head (issue 33).

One pass over the HDTF clip (8 s, 25 fps) through the real pipeline; the figures are those of
``facecapges capture-eval`` (docs/face-capture.md). The clip's last 3 s are the span the jaw's
metric and response were *not* chosen on.
"""

from __future__ import annotations

import pytest

from facecapges.capture.evaluate import evaluate_tracks, run_tracks
from facecapges.errors import UserError


@pytest.fixture(scope="module")
def hdtf_tracks(face_video):
    try:
        return run_tracks(face_video)
    except UserError as exc:
        if "not installed" in str(exc):
            pytest.skip(str(exc))
        raise


def _r(report, name):
    return report["channels"][name]["r"]


def test_jaw_open_meets_its_target_on_the_whole_clip_and_the_held_out_half(hdtf_tracks):
    """jawOpen r ≥ 0.8 over capture-eval's span (2–8 s; was 0.787 with the lower lip's drop alone, γ = 2 and the
    jaw's range from a few seconds of talking) and ≥ 0.9 on the held-out 5–8 s (was 0.887); its mean absolute error
    ≤ 0.09 (was 0.112: a talking jaw read as a full one)."""
    whole = evaluate_tracks(hdtf_tracks, skip_s=2.0)
    held_out = evaluate_tracks(hdtf_tracks, skip_s=5.0)
    assert whole["frames_evaluated"] == 150 and held_out["frames_evaluated"] == 75
    assert _r(whole, "jawOpen") >= 0.8, whole["channels"]["jawOpen"]
    assert whole["targets"]["jawOpen"]["met"]
    assert _r(held_out, "jawOpen") >= 0.9, held_out["channels"]["jawOpen"]
    assert whole["channels"]["jawOpen"]["mae"] <= 0.09, whole["channels"]["jawOpen"]


def test_the_other_main_channels_keep_their_agreement(hdtf_tracks):
    """Smiles and blinks as measured before the jaw change (0.824 / 0.857, 0.892 / 0.878), with a little room."""
    whole = evaluate_tracks(hdtf_tracks, skip_s=2.0)
    for name, bound in (("mouthSmileLeft", 0.8), ("mouthSmileRight", 0.83), ("eyeBlinkLeft", 0.86),
                        ("eyeBlinkRight", 0.85)):
        assert _r(whole, name) >= bound, (name, whole["channels"][name])


def test_a_head_turn_does_not_read_as_a_sideways_jaw(hdtf_tracks):
    """She never shifts her jaw (MediaPipe's jawLeft/Right stay ≤ 0.02) but turns her head by ±20°: the lip offset's
    part that follows the yaw is taken out, so jawLeft + jawRight stay near 0 (mean absolute error was 0.39 over
    2–8 s and 0.50 over 5–8 s, jawLeft 0.6–0.8 whenever she looked aside). r means nothing here: MediaPipe's own
    near-zero jawLeft follows the yaw (r 0.73)."""
    for skip, bound in ((2.0, 0.3), (5.0, 0.3)):
        rep = evaluate_tracks(hdtf_tracks, skip_s=skip)
        mae = rep["channels"]["jawLeft"]["mae"] + rep["channels"]["jawRight"]["mae"]
        assert mae <= bound, (skip, rep["channels"]["jawLeft"], rep["channels"]["jawRight"])
