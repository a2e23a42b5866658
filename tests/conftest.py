"""Shared test configuration.

Rules for every test module: never flip ``jax_enable_x64`` globally (use the scoped
``with jax.enable_x64(True):``), keep each module's runtime small (the whole default suite
must stay under ~15 minutes on 2 cores), and mark long studies ``@pytest.mark.slow``.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
