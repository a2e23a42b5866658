"""Work queues side by side on the CPU cores.

XLA's CPU code spreads the many small kernels of a branch-and-bound round or a SERGE step
badly over threads (two threads are often slower than one), while separate programs run side
by side keep every core busy. Batched solvers therefore deal independent work (problems,
trial blocks) to one queue per usable core and run the queues in threads (the GIL is released
while a compiled program runs); on an accelerator there is one queue.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import jax


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, e.g. under ``taskset``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def default_queues() -> int:
    """One queue per usable core on CPU, one on an accelerator.

    Usable cores are those of the affinity mask (e.g. under ``taskset``).
    """
    return usable_cpus() if jax.default_backend() == "cpu" else 1


def side_by_side(fn: Callable, items: Sequence) -> list:
    """``[fn(x) for x in items]``, with the calls run side by side in threads.

    Each thread keeps the caller's float64 setting, which JAX holds per thread. ``fn`` should
    dispatch jitted programs only, its arguments as NumPy arrays of their final dtype: JAX
    compiles a jitted function once however many threads call it first, but two threads
    dispatching the same new eager op (``jnp.asarray(x, dtype)``, even ``jnp.asarray`` of an
    array of its own dtype) at once each compile it (``tests/test_parallel.py``).
    """
    if len(items) <= 1:
        return [fn(x) for x in items]
    x64 = bool(jax.config.jax_enable_x64)

    def call(x):
        with jax.enable_x64(x64):
            return fn(x)

    with ThreadPoolExecutor(len(items)) as ex:
        return list(ex.map(call, items))


__all__ = ["default_queues", "side_by_side", "usable_cpus"]
