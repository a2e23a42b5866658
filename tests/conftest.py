"""Shared test configuration.

Rules for every test module: never flip ``jax_enable_x64`` globally (use the scoped
``with jax.enable_x64(True):``), keep each module's runtime small (the whole default suite
must stay under ~15 minutes on 2 cores), and mark long studies ``@pytest.mark.slow``.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import atexit  # noqa: E402
import gc  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

from pqrm_jax import compile_cache  # noqa: E402

# JAX's persistent compilation cache, one fresh directory per test process, removed when the
# process exits. ``_release_compiled_programs`` drops every compiled program after a module,
# so a program that several modules (or a module's notebook kernel or command subprocess)
# use was compiled again in each; with the cache it is compiled once per process and loaded
# from disk after that. Nothing is kept between test runs, and every test still compiles
# what it is the first to need. Each process (each xdist worker) has its own directory:
# JAX writes an entry in place, so two processes sharing one could read a half-written
# entry. The environment carries the worker's directory to the subprocesses its tests start
# (one at a time, except the multi-process studies: there a half-written read is a warning
# and a compile, not an error, as jax_raise_persistent_cache_errors is off). Set before any
# program is compiled (JAX decides once per process whether it uses the cache). One directory
# shared by both workers (safe with JAX's file lock, which a size bound turns on) was
# measured and not kept: the suite's ~7 500 compiles took 2 400 s of the workers' 3 230 s,
# and every hit of the shared cache together saved 110 s of it (2026-12-05).
_XLA_CACHE = tempfile.mkdtemp(prefix="pqrm-jax-test-xla-")
atexit.register(shutil.rmtree, _XLA_CACHE, True)
compile_cache.enable(_XLA_CACHE)  # every program cached, whatever its compile time
os.environ["JAX_COMPILATION_CACHE_DIR"] = _XLA_CACHE  # the same for subprocesses
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after every test module.

    An xdist worker lives for the whole suite. Every XLA:CPU executable it keeps maps its
    code into memory, and a worker that kept every program of the suite held ~16 000
    mappings after 4 minutes, growing steadily: a CI worker died with a fatal signal late in
    the run (``node down: Not properly terminated``), consistent with the kernel's limit of
    65 530 mappings per process (``vm.max_map_count``). Clearing the caches between modules
    bounds the mappings and the memory by what one module compiles; a module that needs a
    program twice still compiles it once.
    """
    yield
    jax.clear_caches()
    gc.collect()
