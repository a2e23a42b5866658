"""Counting the programs JAX compiles inside a block (shared by the compile-count tests).

Counted from JAX's own compile log (``jax.log_compiles``), as blackjax's tests do.
"""
import contextlib
import logging
import threading

import jax


class _Collect(logging.Handler):
    """Each log message with whether it came from the main thread and ``probe()`` then."""

    def __init__(self, probe):
        super().__init__(logging.DEBUG)
        self.probe = probe
        self.records: list[tuple[str, bool, object]] = []

    def emit(self, record):
        self.records.append((record.getMessage(),
                             record.thread == threading.main_thread().ident, self.probe()))


@contextlib.contextmanager
def _collect(probe):
    handler = _Collect(probe)
    logger = logging.getLogger("jax")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    compiled: list = []
    try:
        with jax.log_compiles(True):
            yield compiled
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
        compiled += [r for r in handler.records if r[0].startswith("Compiling ")]


@contextlib.contextmanager
def count_compiles():
    """Collect the names of the programs JAX compiles inside the block."""
    with _collect(lambda: None) as records:
        compiled: list[str] = []
        yield compiled
    compiled += [m for m, _, _ in records]


@contextlib.contextmanager
def compiles_by_thread(probe=lambda: None):
    """Collect ``(program name, compiled in the main thread, probe() at that moment)`` for
    every program JAX compiles inside the block (e.g. ``"jit(_solve)"``)."""
    with _collect(probe) as records:
        out: list[tuple[str, bool, object]] = []
        yield out
    out += [(m.split()[1], main, p) for m, main, p in records]
