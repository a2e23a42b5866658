"""Timing helpers shared by the benchmark scripts: wall time with CPU time beside it.

Every :func:`best_of` / :func:`best_of_cpu` / :func:`timed` call is also logged in
:data:`CALLS` (the calling line, wall and CPU seconds), which ``_env.write_result`` stores
under ``timings`` in the result JSON, so every measured time has its CPU time beside it.
CPU time is that of the whole process (every thread), from ``time.process_time``: above the
wall time when XLA uses several cores, about equal on one.
"""

from __future__ import annotations

import inspect
import time

import jax

CALLS: list[dict] = []


def _caller() -> str:
    for frame in inspect.stack()[2:]:
        if frame.filename != __file__:
            line = (frame.code_context or [""])[0].strip()
            return f"{frame.filename.rsplit('/', 1)[-1]}:{frame.lineno} {line[:100]}"
    return "?"


def _timed(f):
    t0, c0 = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(f())
    return time.perf_counter() - t0, time.process_time() - c0, out


def timed(f):
    """(wall seconds, CPU seconds of this process — every thread —, output) of one call of
    ``f``; JAX results are waited for inside the timing."""
    wall, cpu, out = _timed(f)
    CALLS.append({"at": _caller(), "runs": 1, "wall_s": wall, "cpu_s": cpu})
    return wall, cpu, out


def best_of_cpu(f, n: int = 3):
    """(fastest wall time, CPU time of that same run, the last output) of ``n`` runs of ``f``."""
    runs, out = [], None
    for _ in range(n):
        wall, cpu, out = _timed(f)
        runs.append((wall, cpu))
    wall, cpu = min(runs)
    CALLS.append({"at": _caller(), "runs": n, "wall_s": wall, "cpu_s": cpu})
    return wall, cpu, out


def best_of(f, n: int = 3):
    """(fastest of ``n`` wall-clock runs of ``f`` in seconds, the last run's output).

    JAX results are waited for inside the timing; the CPU time of that run is logged in
    :data:`CALLS` (:func:`best_of_cpu` returns it).
    """
    wall, _, out = best_of_cpu(f, n)  # _caller() skips this file's frames: same record
    return wall, out
