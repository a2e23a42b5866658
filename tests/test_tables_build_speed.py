"""The build pipeline's fast paths give exactly what their plain versions give.

Decisions tested: docs/decisions.md §2.3.
"""

import subprocess
import sys
from concurrent.futures.process import BrokenProcessPool
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.calculi import Poly
from pqrm_jax.nlsat import decide_job
from pqrm_jax.tables import certify, exact
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


def test_sample_configs_round_each_operation_once():
    """At the pre-pass's own size class the jitted sampler equals float32 arithmetic with one
    rounding per operation (NumPy on the same draws): written as float32 operations in one
    program, XLA fused ``centre + scale · u`` into a multiply-add and 6 % of the
    coordinates moved by an ulp."""
    key, n = jax.random.PRNGKey(3), 1 << 16
    k1, k2, k3 = jax.random.split(key, 3)
    s = np.asarray([0.6, 1.2, 2.5, 5.0], np.float32)[np.asarray(
        jax.random.randint(k1, (n, 2, 1), 0, 4))]
    c = np.asarray([[0.0, 0.0], [0.0, 0.5], [0.0, 1.0]], np.float32)[np.asarray(
        jax.random.randint(k3, (n, 2), 0, 3))]
    u = np.asarray(jax.random.uniform(k2, (n, 2, 2), minval=-1.0, maxval=1.0))
    np.testing.assert_array_equal(exact.sample_configs(key, n)[:, 2:], c + s * u)


@pytest.mark.parametrize("name", ["edc", "dcc"])
def test_sampled_realised_equals_realised_of_the_samples(name):
    """The pre-pass's one program (draw, classify) gives the configurations and atoms of
    ``sample_configs`` then ``realised``, on every relation."""
    calc = calculi.get(name)
    atoms, _ = pb.atoms(calc)
    key = jax.random.PRNGKey(4)
    rel, pts = exact.sampled_realised(calc, atoms, key, 6000)
    cfg = exact.sample_configs(key, 6000)
    np.testing.assert_array_equal(exact.configs_of(pts), cfg)
    want = exact.realised(calc, atoms, cfg)
    assert rel.keys() == want.keys()
    for k in want:
        np.testing.assert_array_equal(rel[k], want[k])


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



def _api_decide(constraints):
    """z3 on the formula built term by term through its Python API (the plain way):
    (verdict, exact model values where rational, else None)."""
    import z3

    xs = z3.Reals("x0 x1 x2 x3")
    s = z3.SolverFor("QF_NRA")
    for poly, sign in constraints:
        e = z3.RealVal(0)
        for mono, c in poly.terms.items():
            t = z3.RealVal(f"{c.numerator}/{c.denominator}")
            for x, k in zip(xs, mono, strict=True):
                for _ in range(k):
                    t = t * x
            e = e + t
        s.add(e > 0 if sign > 0 else (e < 0 if sign < 0 else e == 0))
    res = s.check()
    if res != z3.sat:
        return str(res), None
    vals = [s.model().eval(x, model_completion=True) for x in xs]
    return str(res), [Fraction(v.numerator_as_long(), v.denominator_as_long())
                      if z3.is_rational_value(v) else None for v in vals]


@pytest.mark.parametrize("name", ["edc", "dcc"])
def test_smtlib_decide_matches_api_formula(name):
    calc = calculi.get(name)
    probs = [pr.constraints for pr in pb.random_compose_problems(calc, 40, seed=3)]
    got = certify.decide_many(probs, workers=1)
    n_sat = 0
    for cons, (verdict, wit) in zip(probs, got, strict=True):
        want, model = _api_decide(cons)
        assert verdict == want
        if verdict == certify.SAT:
            n_sat += 1
            assert pb.verify(pb.Problem(cons), wit)
            assert all(m is None or m == w for m, w in zip(model, wit, strict=True))
    assert 0 < n_sat < len(probs)


def test_smtlib_text_and_verdicts():
    x0, x1 = (Poly.var(2, i) for i in range(2))
    cons = [(x0 * x0 - Fraction(1, 3) * x1 + 2, 1), (x1 - 1, 0), (-x0, -1)]
    assert certify.smtlib(cons).splitlines() == [
        "(declare-fun x0 () Real)", "(declare-fun x1 () Real)",
        "(assert (> (+ (* 1 x0 x0) (* (- (/ 1 3)) x1) 2) 0))",
        "(assert (= (+ (* 1 x1) (- 1)) 0))", "(assert (< (* (- 1) x0) 0))"]
    verdict, wit = certify.decide(cons)
    assert verdict == certify.SAT and pb.verify(pb.Problem(cons), wit)
    assert certify.decide([(x0 * x0 + 1, -1)]) == (certify.UNSAT, None)


def test_decide_many_pool_equals_in_process():
    probs = [pr.constraints for pr in
             pb.random_compose_problems(calculi.get("edc"), certify.MIN_POOL_BATCH, seed=5)]
    assert certify.decide_many(probs, workers=2) == certify.decide_many(probs, workers=1)


def test_decide_many_keeps_its_pool():
    """The z3 pool lives for the process: a second build starts no workers (each start ran
    the caller's main script again, ≈ 1.1 s from a script importing JAX; issue 31 item 4),
    and small batches go to it once it runs."""
    import os

    job = [(Poly.var(1, 0) * Poly.var(1, 0) + Poly.const(1, 1), -1)]
    probs = [job] * certify.MIN_POOL_BATCH
    assert certify.decide_many(probs, workers=2) == [(certify.UNSAT, None)] * len(probs)
    ex = certify.pool(2)
    assert ex.submit(os.getpid).result() != os.getpid()
    assert certify.decide_many(probs[:3], workers=2) == [(certify.UNSAT, None)] * 3
    assert certify.pool(2) is ex
    fresh = certify.pool(2, fresh=True)
    assert fresh is not ex and certify.pool(2) is fresh


def test_decide_many_replaces_a_broken_pool():
    """A kept pool whose worker died (killed, out of memory) is replaced, not fatal."""
    import os

    job = [(Poly.var(1, 0) * Poly.var(1, 0) + Poly.const(1, 1), -1)]
    broken = certify.pool(2)
    with pytest.raises(BrokenProcessPool):
        broken.submit(os._exit, 1).result()
    assert certify.decide_many([job] * 5, workers=2) == [(certify.UNSAT, None)] * 5
    assert certify.pool(2) is not broken


def test_to_batch_equals_entry_by_entry():
    """The vectorised ``to_batch`` fills exactly what filling every entry in turn fills."""
    for name in ("edc", "dcc"):
        calc = calculi.get(name)
        probs = pb.random_compose_problems(calc, 300, seed=3)
        got = pb.to_batch(probs, 8.0)
        K = max(len(pr.constraints) + len(pr.domain) for pr in probs)
        want = {f: np.zeros_like(getattr(got, f)) for f in ("A", "b", "c", "sign", "active")}
        used = np.zeros((len(probs), pb.NV), bool)
        for i, pr in enumerate(probs):
            for k, (poly, s) in enumerate(pr.constraints + pr.domain):
                c, b, A = poly.quadratic_form()
                want["c"][i, k], want["b"][i, k], want["A"][i, k] = c, b, A
                want["sign"][i, k], want["active"][i, k] = s, True
                used[i, list(poly.variables())] = True
        assert got.A.shape[1] == K
        for f, w in want.items():
            np.testing.assert_array_equal(getattr(got, f), w)
        np.testing.assert_array_equal(got.lo, np.where(used, -8.0, 0.0))
        np.testing.assert_array_equal(got.hi, np.where(used, 8.0, 0.0))


def test_z3_workers_start_without_jax():
    """The pool's workers import z3, not JAX (2.4 s each on the old spawned pool; docs/tables.md
    §method): the worker module alone, and a worker of the pool itself."""
    from concurrent.futures import ProcessPoolExecutor

    code = "import sys, pqrm_jax.nlsat; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    ctx = certify.pool_context()
    assert ctx.get_start_method() != "fork"  # JAX's threads make forking the caller unsafe
    job = (certify.smtlib([(Poly.var(1, 0) * Poly.var(1, 0) + Poly.const(1, 1), -1)]), 1, 10**6)
    with ProcessPoolExecutor(1, mp_context=ctx) as ex:  # one worker: both calls run in it
        assert ex.submit(decide_job, job).result() == (certify.UNSAT, None)
        in_worker = ex.submit(eval, "'jax' in __import__('sys').modules").result()
    if ctx.get_start_method() == "forkserver":
        assert in_worker is False


def test_adjacency_radius_is_the_decimal_written():
    calc = calculi.get("edc")
    atoms, _ = pb.atoms(calc)
    p, q = atoms[0], atoms[1]
    exact_r = pb.adjacency_problem(calc, p, q, Fraction(1, 100)).constraints
    assert pb.adjacency_problem(calc, p, q, 1e-2).constraints == exact_r
    assert all(c.denominator <= 10**4 for poly, _ in exact_r for c in poly.terms.values())


def _fraction_signs(calc, X, Y, Z):
    """exact_signs the plain way: f(u/n, v/n, m/n) in Fractions."""
    X, Y, Z = ([Fraction(v) for v in P] for P in (X, Y, Z))
    dx, dy, ex, ey = Y[0] - X[0], Y[1] - X[1], Z[0] - X[0], Z[1] - X[1]
    n, m = dx * dx + dy * dy, ex * ex + ey * ey
    if n == 0:
        return "tri" if m == 0 else "dou"
    u, v = ex * dy - ey * dx, ex * dx + ey * dy
    return tuple((val > 0) - (val < 0) for val in
                 (p.evaluate([u / n, v / n, m / n]) for p in calc.constraints))


def test_integer_exact_signs_equal_fraction_evaluation():
    from pqrm_jax.calculi import Calculus, alpha, beta, rho

    odd = Calculus.from_rule(  # fractional coefficients and a circle off the axis
        "odd_coeffs_t", [Fraction(2, 3) * alpha - Fraction(1, 7) * beta + Fraction(1, 5),
                         Fraction(1, 3) - rho + Fraction(1, 2) * alpha],
        lambda s: "".join("+" if x > 0 else "-" for x in s), ["++", "+-", "-+", "--"])
    rng = np.random.default_rng(0)
    for calc in (calculi.get("edc"), calculi.get("dcc"), odd):
        for t in range(3000):
            if t % 3 == 0:  # small integers: collinear, coincident and boundary cases
                P = rng.integers(-2, 3, (3, 2)).tolist()
            elif t % 3 == 1:
                num, den = rng.integers(-9, 10, (3, 2)), rng.integers(1, 8, (3, 2))
                P = [[Fraction(int(a), int(b)) for a, b in zip(r, s, strict=True)]
                     for r, s in zip(num, den, strict=True)]
            else:  # float32 samples, as the pre-pass draws them
                P = rng.uniform(-5, 5, (3, 2)).astype(np.float32).astype(float).tolist()
            assert exact.exact_signs(calc, *P) == _fraction_signs(calc, *P), (calc.name, P)
    # every number type a caller may pass is read exactly (NumPy scalars, ints, text)
    edc = calculi.get("edc")
    f32 = rng.uniform(-5, 5, (200, 3, 2)).astype(np.float32)
    for P in f32:
        want = _fraction_signs(edc, *P.astype(float).tolist())
        assert exact.exact_signs(edc, *P) == want  # np.float32 scalars
        assert exact.exact_signs(edc, *P.astype(np.float64)) == want
    P = [["0", "0"], ["0", "1"], ["1/3", "2/3"]]
    assert exact.exact_signs(edc, *P) == _fraction_signs(
        edc, *[[Fraction(v) for v in r] for r in P])
    assert exact.exact_signs(edc, *np.array([[0, 0], [0, 1], [1, 1]])) == _fraction_signs(
        edc, [0, 0], [0, 1], [1, 1])


@pytest.mark.parametrize(("base", "cols", "n"), [(20, 3, 100_000), (5, 2, 50), (300, 3, 1000),
                                                 (7, 1, 0)])
def test_first_rows_equals_unique(base, cols, n):
    from pqrm_jax.tables import build

    key = np.random.default_rng(base).integers(0, base, (n, cols))
    code = np.zeros(n, np.int64)
    for col in key.T:
        code = code * base + col
    np.testing.assert_array_equal(build._first_rows(key, base),
                                  np.unique(code, return_index=True)[1])


@pytest.mark.parametrize("name", ["edc", "dcc"])
def test_compose_problem_equals_simplify_of_its_relations(name):
    calc = calculi.get(name)
    atoms, _ = pb.atoms(calc)
    rng = np.random.default_rng(0)
    for i, j, k in rng.integers(0, len(atoms), (1500, 3)):
        p, q, r = atoms[i], atoms[j], atoms[k]
        F = pb.frame(p)
        A, B, C, D = F["A"], F["B"], F["C"], F["D"]
        want = pb.simplify(pb.relation(calc, p, A, B, C) + pb.relation(calc, q, B, C, D)
                           + pb.relation(calc, r, A, B, D))
        assert pb.compose_problem(calc, p, q, r).constraints == want  # same list, in order
