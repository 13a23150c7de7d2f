"""Objective evaluation of generated gestures (thesis 5.5–5.7).

Every metric is a plain function over arrays of upper-body poses, (T, 47, 6) rot6d in
``facecapges.skeleton.UPPER_BODY`` order, with frame rates and sample rates in the
signatures:

* :mod:`~facecapges.evaluation.fgd` — the skeleton-aware motion autoencoder and the
  Fréchet Gesture Distance (eq. 5.3, 5.4, 5.6, 5.7).
* :mod:`~facecapges.evaluation.srgr` — Semantic-Relevance Gesture Recall (eq. 5.8).
* :mod:`~facecapges.evaluation.beat_align` — BeatAlign (eq. 5.9–5.10) and its
  shifted-audio control.
* :mod:`~facecapges.evaluation.l1div` — L1 diversity (eq. 5.11) and the per-sequence
  deviation from the temporal mean.
* :mod:`~facecapges.evaluation.synchrony` — synchrony controls: audio-energy / wrist-speed
  correlation against shifted audio (z), BeatAlign gap in sd units, wrist jerk and spread
  as ratios to the real motion.
* :mod:`~facecapges.evaluation.realism` — issue #25 §3, for any engine: transitions (frames above
  the real motion's 99.9th-percentile joint acceleration), repetition against a database (longest
  verbatim copy, share used, returns within 20 s), wrist spread in pauses vs speech, and a
  real-vs-generated window classifier with its real-vs-real control.
* :mod:`~facecapges.evaluation.peers` — BA, SRGR and L1div exactly as BEAT/CaMN's and
  EMAGE's scripts compute them (for comparisons with published numbers).
* :mod:`~facecapges.evaluation.regions` — the two evaluation regions (5.5.5).
* :mod:`~facecapges.evaluation.baselines` — reference rows (ground truth, mean pose,
  random real segment).
* :mod:`~facecapges.evaluation.camn` — the CaMN baseline network (thesis 5.2.1), trained by
  the project's trainer as a variant and evaluated by ``ablate``; why DiffSHEG is absent.
* :mod:`~facecapges.evaluation.suite` — all metrics for several methods in both regions.
* :mod:`~facecapges.evaluation.report` — ``metrics.json``, the Table 5.2 Markdown
  table and the PNG plots.
* :mod:`~facecapges.evaluation.run` — ``facecapges eval`` end to end (checkpoint +
  cache → report); :mod:`~facecapges.commands.evaluation` — ``fgd-train``, ``eval`` and
  ``ablate``.
* :mod:`~facecapges.evaluation.ablate` — the ablation study of 5.7 (Table 5.3): full
  model, without head pose, offline decoding (:mod:`facecapges.network.bidirectional`) and the
  CaMN baseline, trained with one recipe and evaluated on the held-out frames.
* :mod:`~facecapges.benchmarks.evaluation` — speed of the evaluation tools and the
  peer-architecture timing (FaceCapGes streaming vs CaMN online/offline).

The side-by-side skeleton video is :mod:`facecapges.avatar.render.skeleton_video`.
"""
