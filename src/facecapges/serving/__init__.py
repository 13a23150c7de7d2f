"""Serving many live streams at once: ``facecapges serve`` (WebSocket, batched model calls).

* :mod:`.server` — the WebSocket server: one connection = one stream (own history and
  LSTM state, a slot of :class:`facecapges.network.batched.BatchedNetworkStreams`),
  all streams due in a tick stepped as one batched call; messages in the format of
  :mod:`facecapges.runtime.outputs.protocol`.
* :mod:`.loadgen` — simulated live clients (the benchmark's and the tests' load).
* :mod:`facecapges.benchmarks.serving` — ``streams_at_15fps``.
* :mod:`facecapges.commands.serving` — the ``serve`` command.
"""
