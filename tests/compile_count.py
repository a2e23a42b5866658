"""Counting the programs JAX compiles inside a block (shared by the compile-count tests).

Counted from JAX's own compile log (``jax.log_compiles``), as blackjax's tests do.
"""
import contextlib
import logging

import jax


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def count_compiles():
    """Collect the names of the programs JAX compiles inside the block."""
    handler = _Collect()
    logger = logging.getLogger("jax")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    compiled: list[str] = []
    try:
        with jax.log_compiles(True):
            yield compiled
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
        compiled += [m for m in handler.messages if m.startswith("Compiling ")]
