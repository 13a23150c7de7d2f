"""The real-time runtime: video or devices in → avatar out (thesis 2.4).

The data path of one frame at the model rate, one module each:

* :mod:`.sources` — where frames come from: a video file with its audio track (or a
  WAV), a camera + microphone, the iPhone Live Link Face app over UDP
  (:mod:`.livelink` decodes its packets), RGB-D frames from files;
* :mod:`.scheduler` — the model-rate clock: aligns audio samples, face and head to
  frame ``k``, runs the capture and the :class:`~facecapges.model.streaming.StreamingGenerator`
  once per frame, never waits for future input, times every stage and applies the
  documented fallbacks (face lost, audio underrun, dropped/late frames);
* :mod:`.sinks` — BVH and BEAT face-JSON recorders; :mod:`.vmc` — the VMC protocol
  over OSC/UDP (the BEAT → Unity HumanBodyBones table lives there);
* :mod:`.protocol` — the WebSocket message format (viewer feed now, ``serve`` later);
  :mod:`.web_server` — the loopback HTTP + WebSocket server of the browser viewer
  (``facecapges/web/viewer.html``);
* :mod:`facecapges.commands.runtime` — ``facecapges run`` and ``facecapges live``; :mod:`.offline` — the
  files ``run`` writes (report, avatar and side-by-side videos); :mod:`facecapges.benchmarks.runtime` — speed,
  the 60 s ``run`` and the long simulated live session.
"""
