"""The one timing rule the benchmarks share: one warm-up call, then the median of ``repeats``
timed calls, each waited for (``sync``: torch.cuda.synchronize on CUDA, where kernels run
asynchronously)."""

from __future__ import annotations

import statistics
import time
from typing import Callable


def median_ms(fn: Callable[[], object], repeats: int, sync: Callable[[], None] = lambda: None) -> float:
    """Median wall time of ``fn()`` in milliseconds after one warm-up (JIT, allocator, caches)."""
    fn()
    times = []
    for _ in range(repeats):
        sync()
        start = time.perf_counter()
        fn()
        sync()
        times.append(1000.0 * (time.perf_counter() - start))
    return statistics.median(times)
