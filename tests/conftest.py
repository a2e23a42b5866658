"""Shared test configuration.

Rules for every test module: never flip ``jax_enable_x64`` globally (use the scoped
``with jax.enable_x64(True):``), keep each module's runtime small (the whole default suite
must stay under ~15 minutes on 2 cores), and mark long studies ``@pytest.mark.slow``.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import gc  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402


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
