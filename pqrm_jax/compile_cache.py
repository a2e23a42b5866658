"""JAX's persistent compilation cache for the ``pqrm-jax`` command (warm starts).

A study or table build compiles its programs once per process; with the cache on, a second
process loads them from disk instead of compiling (docs/benchmarks.md §warm-starts). The
``pqrm-jax`` command turns it on by default (:func:`enable`); library calls leave JAX's own
setting alone (the test suite gives each test process a fresh directory, tests/conftest.py).

Location, in order:

* ``PQRM_JAX_COMPILE_CACHE`` — a directory, or ``off`` (also ``0``, ``no``, ``false``,
  ``none`` or empty) to turn the cache off;
* JAX's own ``JAX_COMPILATION_CACHE_DIR`` / ``jax_compilation_cache_dir``, when already set, is
  kept as it is;
* else ``$XDG_CACHE_HOME/pqrm-jax/xla`` (default ``~/.cache/pqrm-jax/xla``).

Every program is cached whatever its compile time (a study's many small programs add up).
An entry is keyed by JAX on the program, the JAX/jaxlib versions, the backend and the compile
options, so a stale entry is never used; the directory may be deleted at any time.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

__all__ = ["ENV", "OFF", "default_location", "location", "enable"]

ENV = "PQRM_JAX_COMPILE_CACHE"
OFF = frozenset({"", "0", "off", "no", "false", "none"})


def default_location() -> Path:
    """``$XDG_CACHE_HOME/pqrm-jax/xla`` (``~/.cache/pqrm-jax/xla`` without the variable)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "pqrm-jax" / "xla"


def location(environ: dict | None = None) -> Path | None:
    """The cache directory :func:`enable` would use, or None when it is turned off.

    Args:
        environ: the environment to read (default ``os.environ``).

    Returns:
        The directory, or None.

    >>> location({"PQRM_JAX_COMPILE_CACHE": "off"}) is None
    True
    >>> str(location({"PQRM_JAX_COMPILE_CACHE": "/tmp/c"}))
    '/tmp/c'
    >>> str(location({"XDG_CACHE_HOME": "/x"}))
    '/x/pqrm-jax/xla'
    """
    env = os.environ if environ is None else environ
    if ENV in env:
        value = env[ENV].strip()
        return None if value.lower() in OFF else Path(value).expanduser()
    if environ is not None and "XDG_CACHE_HOME" in environ:
        return Path(environ["XDG_CACHE_HOME"]) / "pqrm-jax" / "xla"
    return default_location()


def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turn JAX's persistent compilation cache on; returns its directory (None: off).

    ``path`` overrides the environment. A directory JAX was already given (its own variable or
    config) is kept. A directory that cannot be created turns the cache off with a warning
    (the command still runs, compiling as before).

    Args:
        path: the cache directory (default: :func:`location`).

    Returns:
        The directory in use, or None when the cache is off.
    """
    import jax

    current = jax.config.jax_compilation_cache_dir
    if path is None and ENV not in os.environ and current:
        where = Path(current)
    else:
        where = Path(path) if path is not None else location()
        if where is None:
            return None
        try:
            where.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            warnings.warn(f"compilation cache off: cannot create {where} ({exc}); set "
                          f"{ENV}=DIR or {ENV}=off", stacklevel=2)
            return None
        jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return where
