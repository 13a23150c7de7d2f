"""One error policy: the same condition is the same error everywhere, and process-wide state a
session changes is given back."""

from __future__ import annotations

import pytest
import torch

from facecapges.errors import UserError
from facecapges.skeleton import Skeleton


def test_a_skeleton_without_beat_joints_is_a_user_error_everywhere():
    import numpy as np

    from facecapges.avatar.body import check_skeleton
    from facecapges.runtime.outputs.vmc import VmcMapping

    skel = Skeleton(names=["Hips", "Spine"], parents=np.array([-1, 0]), offsets=np.zeros((2, 3)),
                    channels=[["Xrotation"], ["Xrotation"]], end_sites={})
    for check in (lambda: check_skeleton(skel), lambda: VmcMapping(skel)):
        with pytest.raises(UserError, match="not a BEAT skeleton"):
            check()


def test_a_session_gives_back_torch_threads(face_video, default_checkpoint):
    from facecapges.runtime.session import build_session

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        sess = build_session(default_checkpoint, video=face_video, silent_ok=True)
        assert torch.get_num_threads() == 1  # one thread while live (see build_session)
        sess.close()
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
