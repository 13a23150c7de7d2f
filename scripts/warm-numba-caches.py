"""Fill the on-disk machine-code caches of every Numba function the project runs, in one process.

Run once by ``make setup``, after the install. Two reasons:

* our streaming kernel (:func:`facecapges.network.native.warm`), the matching engine's loops
  (:func:`facecapges.matching.kernels.warm`), the rotations' (:func:`facecapges.rotations_compiled.checked_rot6d_to_quaternions`)
  the VMC sender's (:func:`facecapges.runtime.outputs.vmc_kernels.warm`) and the VRM presets'
  (:func:`facecapges.avatar.vrm.expressions_compiled.warm`): compiled here, not by a stream's first
  frame (nor by a sender's construction in ``live``);
* librosa's Numba functions (``cache=True``): its ufuncs and gufuncs with explicit signatures compile when
  librosa is imported, the others on their first call, and each writes its cache into librosa's own
  ``__pycache__``. Two processes doing that at the same time (the suite's two pytest-xdist workers on a fresh
  venv, or two helpers' jobs) can leave an index that points at another variant's code: every later
  ``librosa.onset.onset_detect`` then dies with a segmentation fault in ``util.peak_pick`` (seen on
  2026-12-04 with numba 0.68.1, librosa 0.11.0: the crash went away when the cache was deleted and rebuilt by
  one process). Filling the caches here, once, leaves the later processes only reading them.
"""

from __future__ import annotations

import numpy as np


def main() -> None:
    from facecapges.avatar.vrm import expressions_compiled
    from facecapges.matching import kernels
    from facecapges.runtime.outputs import vmc_kernels

    kernels.warm()  # the streaming kernel's functions too (network.native.warm)
    from facecapges.rotations_compiled import checked_rot6d_to_quaternions

    checked_rot6d_to_quaternions()  # serve's model process: a tick's quaternions
    from facecapges.capture import mouth_kernels
    from facecapges.runtime.head import compiled_head

    compiled_head()  # live's output stage: the head's chain
    mouth_kernels.checked()  # and the speech mouth's sums
    from facecapges.capture import kernels as capture_kernels

    capture_kernels.compiled()  # the face capture's steps after MediaPipe (live, capture)
    from facecapges.io import bvh_text

    bvh_text.checked()  # the BVH recorder's text (live, run)
    vmc_kernels.warm()
    expressions_compiled.warm()
    import librosa  # compiles the eager-signature (g)ufuncs into the cache

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        y = rng.standard_normal(16000 * 3).astype(dtype)
        env = librosa.onset.onset_strength(y=y, sr=16000)
        peaks = librosa.onset.onset_detect(onset_envelope=env, sr=16000)
        librosa.onset.onset_detect(y=y, sr=16000, units="time")
        librosa.onset.onset_backtrack(peaks, env)
        librosa.feature.rms(y=y)
        librosa.feature.melspectrogram(y=y, sr=16000)


if __name__ == "__main__":
    main()
