"""Timing helper shared by the benchmark scripts."""

from __future__ import annotations

import time

import jax


def best_of(f, n: int = 3):
    """(fastest of ``n`` wall-clock runs of ``f`` in seconds, the last run's output).

    JAX results are waited for inside the timing.
    """
    ts, out = [], None
    for _ in range(n):
        t0 = time.perf_counter()
        out = jax.block_until_ready(f())
        ts.append(time.perf_counter() - t0)
    return min(ts), out
