"""One BLAS thread for a stream's small products (``live``, ``generate``, ``serve``'s model process).

NumPy's BLAS (OpenBLAS) starts a thread per core and splits a product over them from a few thousand
multiply–adds on: the matching engine's and the speech predictor's products are that small, so on a
2-core machine beside MediaPipe the second thread mostly spins and waits (measured: the predictor's
batched step at 256 streams took 67–99 ms of CPU with OpenBLAS's default threads, 29 ms with one; a
one-stream step the same time either way). torch's own thread count is set beside it where torch is
loaded (a network style); this is the same rule for NumPy. :func:`limit_threads` does both, torch's only
when a network style has already imported it: a matching style runs without torch (issue 36: memory).
"""

from __future__ import annotations

import sys
from typing import Any


def limit_blas_threads(n: int = 1) -> Any:
    """Limit NumPy's BLAS to ``n`` threads in this process; returns the limiter (``restore_original_limits()``)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=max(1, int(n)), user_api="blas")


def limit_threads(n: int = 1) -> Any:
    """Limit NumPy's BLAS and, when torch is loaded (a network style), torch to ``n`` threads in this
    process; never imports torch. Returns a restorer (``restore_original_limits()``) of both."""
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    blas = limit_blas_threads(n)
    if torch is not None:
        torch.set_num_threads(max(1, int(n)))

    class _Restore:
        def restore_original_limits(self) -> None:
            # BLAS first: restoring an OpenMP-built BLAS's threads also resets the process's OpenMP threads,
            # which are torch's (measured: torch left at 1 when torch was restored first)
            blas.restore_original_limits()
            if torch is not None and before is not None:
                torch.set_num_threads(before)

    return _Restore()
