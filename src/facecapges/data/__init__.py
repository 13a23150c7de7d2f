"""BEAT data: file naming and splits, per-clip readers, the prepared cache.

* :mod:`facecapges.data.beat` — clip names, the train/val/test rule, semantic and
  emotion side files, finding clips under a folder.
* :mod:`facecapges.data.prepare` — BEAT folder → cache (``facecapges prepare``).
* :mod:`facecapges.data.cache` — the cache layout and :class:`~facecapges.data.cache.Cache`,
  the loader training and evaluation use.

Nothing is imported here so ``facecapges --help`` stays fast.
"""
