"""The real-time runtime: video or devices in → avatar out (thesis 2.4).

The data path of one frame at the model rate, one module each:

* :mod:`.inputs` — where frames come from: :mod:`.inputs.sources` (a video file with its
  audio track (or a WAV), a camera + microphone, the iPhone Live Link Face app over UDP
  (:mod:`.inputs.livelink` decodes its packets), RGB-D frames from files);
* :mod:`.scheduler` — the model-rate clock: aligns audio samples, face and head to
  frame ``k``, runs the capture and the :class:`~facecapges.network.streaming.NetworkStream`
  once per frame, never waits for future input, times every stage and applies the
  documented fallbacks (face lost, audio underrun, dropped/late frames);
* :mod:`.outputs` — where frames go: :mod:`.outputs.recorders` (BVH and BEAT face-JSON
  recorders), :mod:`.outputs.vmc` (the VMC protocol over OSC/UDP; the BEAT → Unity
  HumanBodyBones table lives there), :mod:`.outputs.upsample`, :mod:`.outputs.protocol`
  (the WebSocket message format of the viewer feed and ``serve``), :mod:`.outputs.viewer`
  (the loopback HTTP + WebSocket server of the browser viewer, ``facecapges/web/viewer.html``)
  and :mod:`.outputs.vrm_viewer`;
* the use cases: :mod:`.run` — the files ``facecapges run`` writes (report, avatar and
  side-by-side videos); :mod:`.live` — ``facecapges live``; :mod:`.generate` —
  ``facecapges generate`` as a function; :mod:`facecapges.commands.runtime` — their command line;
  :mod:`facecapges.benchmarks.runtime` — speed, the 60 s ``run`` and the long simulated live session.
"""
