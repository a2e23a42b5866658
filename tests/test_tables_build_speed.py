"""The build pipeline's fast paths give exactly what their plain versions give (SPEC §2.3)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.tables import exact
from pqrm_jax.tables import problems as pb


def _eager_samples(key, n):
    """The pre-pass sampler as plain eager JAX (what the jitted draws must reproduce)."""
    k1, k2, k3 = jax.random.split(key, 3)
    scales = jnp.asarray([0.6, 1.2, 2.5, 5.0])
    s = scales[jax.random.randint(k1, (n, 2, 1), 0, 4)]
    centres = jnp.asarray([[0.0, 0.0], [0.0, 0.5], [0.0, 1.0]])
    c = centres[jax.random.randint(k3, (n, 2), 0, 3)]
    pts = c + s * jax.random.uniform(k2, (n, 2, 2), minval=-1.0, maxval=1.0)
    A = jnp.zeros((n, 1, 2))
    B = jnp.broadcast_to(jnp.asarray([0.0, 1.0]), (n, 1, 2))
    return np.asarray(jnp.concatenate([A, B, pts], 1), np.float64)


@pytest.mark.parametrize("seed", [0, 7])
def test_sample_configs_bitwise_equal_eager(seed):
    key = jax.random.PRNGKey(seed)
    np.testing.assert_array_equal(exact.sample_configs(key, 5000), _eager_samples(key, 5000))


@pytest.mark.parametrize("name", ["edc", "dcc"])
def test_realised_equals_eager_atoms(name):
    calc = calculi.get(name)
    atoms, _ = pb.atoms(calc)
    cfg = (exact.grid_configs(2) if calc.boundary_inclusive
           else exact.sample_configs(jax.random.PRNGKey(1), 4000))
    got = exact.realised(calc, atoms, cfg)
    lut = exact.atom_lookup(calc, atoms)
    dou = atoms.index("dou") if "dou" in atoms else -1
    tri = atoms.index("tri") if "tri" in atoms else -1
    with jax.enable_x64(True):
        P = jnp.asarray(cfg, jnp.float64)
        for key, (x, y, z) in {"abc": "012", "bca": "120", "cab": "201", "bac": "102",
                               "bcd": "123", "abd": "013"}.items():
            want = exact._atoms_of(calc, lut, dou, tri, P[:, int(x)], P[:, int(y)], P[:, int(z)])
            np.testing.assert_array_equal(got[key], np.asarray(want))
