"""pqrm-jax: qualitative relational mapping and navigation as vectorised JAX programs.

Subpackages follow the papers' concepts: ``calculi`` (docs/decisions.md §2), ``tables``
(exact operator tables), ``pqrm`` (P ch. 2), and more as they land. See README.md.
"""

from . import calculi

__all__ = ["calculi"]
__version__ = "0.1.0"
