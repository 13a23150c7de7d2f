"""Sources: a video file on the stream clock (skips, loop), RGB-D depth frames through the capture."""

from __future__ import annotations

import json
import math

import numpy as np

from facecapges.runtime.inputs.sources import FileVideo
from runtime_helpers import checkpoint


def test_file_video_newest_frame_before_deadline_and_loop(face_video):
    v = FileVideo(face_video)
    try:
        assert v.fps == 25
        f = v.next_frame(1 / 15)  # frames at 0 and 0.04 are due: the newest one, the other skipped
        assert f.ts_s == 0.04 and v.skipped == 1 and f.image.shape == (512, 512, 3)
        assert v.next_frame(1 / 15) is None  # nothing new before the same deadline
        f = v.next_frame(2 / 15)
        assert f.ts_s == 0.12 and v.skipped == 2
        assert v.next_frame(0.1) is None  # never a frame from the past twice, never one from the future
    finally:
        v.close()
    v = FileVideo(face_video, loop_period_s=8.0)
    try:
        f = v.next_frame(8.0)
        assert f.ts_s == 7.96
        f = v.next_frame(8.05)
        assert v.loops == 1 and f.ts_s == 8.04  # second pass, stamped on the stream clock
    finally:
        v.close()


def test_file_video_one_decoding_thread_gives_the_same_frames(face_video):
    """``decode_threads=1`` (``live --realtime`` on a file): FFmpeg decodes with one thread, the frames are the
    same bytes as with its own choice of threads, after a loop's reopening too."""
    import cv2

    a, b = FileVideo(face_video, loop_period_s=1.0), FileVideo(face_video, loop_period_s=1.0, decode_threads=1)
    try:
        assert b._src.cap.get(cv2.CAP_PROP_N_THREADS) == 1
        for k in range(1, 25):  # 1.6 s at 15 fps: across the loop's end
            fa, fb = a.next_frame(k / 15), b.next_frame(k / 15)
            assert fa.ts_s == fb.ts_s and np.array_equal(fa.image, fb.image)
        assert a.loops == b.loops == 1 and b._src.cap.get(cv2.CAP_PROP_N_THREADS) == 1
    finally:
        a.close()
        b.close()


def test_session_runs_opencv_on_one_thread_and_restores_it(face_video):
    import cv2

    from facecapges.runtime.session import build_session

    before = cv2.getNumThreads()
    sess = build_session(checkpoint(), video=face_video, silent_ok=True)
    try:
        assert cv2.getNumThreads() == 1
    finally:
        sess.close()
    assert cv2.getNumThreads() == before


def test_file_video_drop_reads_past_due_frames_across_a_loop(face_video):
    """What the scheduler does behind the clock: every frame due is passed over (not handed out), the next
    one still comes, on the stream clock; across the loop's end too."""
    v = FileVideo(face_video, loop_period_s=8.0)
    try:
        assert v.drop(1.0) == 25  # frames 0 … 0.96
        assert v.drop(1.0) == 0 and v.skipped == 0  # dropped is not skipped (decimation)
        f = v.next_frame(1.05)
        assert f.ts_s == 1.04 and v.skipped == 1  # 1.00 skipped for the newer 1.04, as before
        assert v.drop(8.1) == 173 + 3 and v.loops == 1  # 1.08 … 7.96, then 8.00 … 8.08 of the second pass
        assert v.next_frame(8.15).ts_s == 8.12
    finally:
        v.close()


def test_rgbd_depth_frames_drive_the_head(face_video, tmp_path):
    from facecapges import rotations as rot
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.depth import render_depth
    from facecapges.capture.head_pose import Intrinsics
    from facecapges.capture.models import resolve_model
    from facecapges.rotations import angles_to_matrix
    from facecapges.runtime.session import build_session

    mesh = load_canonical_mesh(resolve_model())
    K = Intrinsics(200.0, 200.0, 80.0, 60.0)
    ddir = tmp_path / "depth"
    ddir.mkdir()
    R = angles_to_matrix(math.radians(20.0), 0.0, 0.0)  # the depth says: turned 20°
    D = render_depth(mesh.vertices / 100 @ R.T + [0, 0, -0.6], mesh.triangles, K, 160, 120, background_mm=1500)
    for i in range(12):
        np.save(ddir / f"{i:04d}.npy", D)
    (tmp_path / "K.json").write_text(json.dumps({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy}))
    sess = build_session(checkpoint(), video=face_video, depth_dir=ddir, intrinsics=tmp_path / "K.json")
    outs = []
    try:
        sess.scheduler.run(max_frames=6, on_frame=outs.append)
    finally:
        sess.close()
    assert len(outs) == 6
    errs = []
    for o in outs:
        err = math.degrees(float(rot.geodesic_angle(rot.rot6d_to_matrix(o.head.astype(np.float64)), R)))
        errs.append(err)
    # the landmarks alone would say ~0° (the woman faces the camera); the first frame is the
    # template registration from scratch, later frames refine it
    assert errs[0] < 6.0 and max(errs[1:]) < 3.0
