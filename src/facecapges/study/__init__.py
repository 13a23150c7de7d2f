"""User study: blind side-by-side ranking of K gesture versions per clip (thesis 5.3).

* :mod:`~facecapges.study.criteria` — the three criteria (realism, synchrony,
  diversity), the thesis's wording and our translation;
* :mod:`~facecapges.study.design` — balanced Latin squares (Williams designs) for the
  clip order, balanced random screen positions of the systems;
* :mod:`~facecapges.study.clips` — ``CLIPS.yaml`` and its checks;
* :mod:`~facecapges.study.build` — the study folder (``study create``);
* :mod:`~facecapges.study.store` — append-only, atomically written answer files;
* :mod:`~facecapges.study.server` and ``page/`` — the participant's page (``study serve``);
* :mod:`~facecapges.study.analyze` — mean ranks, Friedman + post-hoc tests, plots
  (``study analyze``).
"""
