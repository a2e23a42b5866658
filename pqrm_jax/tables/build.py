"""Build exact operator tables for a calculus (docs/decisions.md §2.3, M§III, M§V).

Offers the table build of a constraint-defined calculus (unary operators, composition,
adjacency, each present entry with a witness and every undecided problem listed with its
verdict), the exact unions for merged calculi, and the neighbour distances.

The four-stage pipeline (witness pre-pass, branch-and-bound, path consistency, z3) and mirror
symmetry: docs/tables.md §build.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from ..calculi.calculus import Calculus
from . import certify, exact, symmetry
from . import problems as pb
from .feasibility import FEASIBLE, INFEASIBLE, solve
from .store import UNARY

_UNARY_KEY = {"left": "bca", "right": "cab", "inverse": "bac"}


def _coords(frame: dict, x) -> list[list[float]]:
    pts = []
    for name in "ABCD":
        P = frame[name]
        pts.append([float(P[0].evaluate(list(x))), float(P[1].evaluate(list(x)))])
    return pts


class _Decider:
    """Decides lists of problems: witnesses given → B&B → z3; keeps records."""

    def __init__(self, box, progress, pool, max_iters, certify_all=False, solver=solve):
        self.box, self.progress, self.pool, self.max_iters = box, progress, pool, max_iters
        self.solver = solver
        self.certify_all = certify_all
        self.undecided: list[dict] = []
        self.stats = {"problems": 0, "trivial": 0, "prepass": 0, "bnb_feasible": 0,
                      "bnb_infeasible": 0, "bnb_undecided": 0, "z3_sat": 0, "z3_unsat": 0,
                      "open": 0, "bnb_seconds": 0.0, "z3_seconds": 0.0,
                      "z3_confirmed_infeasible": 0, "z3_overturned": 0,
                      "mirror_copies": 0, "pc_infeasible": 0}
        self.presolved: dict = {}  # problem tag → (status, witness) from a joint B&B call

    def _bnb(self, problems: list[pb.Problem], desc: str) -> None:
        """One B&B call for problems not decided yet (verdicts kept by tag)."""
        todo = [pr for pr in problems if pr.tag not in self.presolved]
        if not todo:
            return
        t0 = time.perf_counter()
        sol = self.solver(pb.to_batch(todo, self.box), pool=self.pool,
                          max_iters=self.max_iters, progress=self.progress, desc=desc)
        self.stats["bnb_seconds"] += time.perf_counter() - t0
        for pr, st, x in zip(todo, sol.status, sol.witness, strict=True):
            self.presolved[pr.tag] = (int(st), x)

    def presolve(self, problems: list[pb.Problem]) -> None:
        """Branch-and-bound, in one batch, the problems that later :meth:`run` calls will need.

        One compiled program instead of one per batch shape; ``run`` then takes their verdicts
        from here. Verdicts do not depend on the batching (probe points are drawn per problem).
        """
        self._bnb([pr for pr in problems if not pr.trivially_infeasible], "branch-and-bound")

    def run(self, name: str, problems: list[pb.Problem], known: dict[int, list],
            refine=None) -> tuple:
        """→ (feasible bool array, witness coordinates per index).

        ``refine(feasible, undecided) -> refuted`` (bool arrays over the problems) may refute
        B&B-undecided problems exactly before they go to z3 (path consistency)."""
        n = len(problems)
        feas = np.zeros(n, bool)
        wit: dict[int, list] = {}
        self.stats["problems"] += n
        for i, w in known.items():
            feas[i] = True
            wit[i] = w
        self.stats["prepass"] += len(known)
        todo = [i for i in range(n) if i not in known and not problems[i].trivially_infeasible]
        self.stats["trivial"] += sum(problems[i].trivially_infeasible for i in range(n))
        if todo:
            self._bnb([problems[i] for i in todo], name)
            status, xs = zip(*(self.presolved[problems[i].tag] for i in todo), strict=True)
            leftover = []
            for i, st, x in zip(todo, status, xs, strict=True):
                pr = problems[i]
                if st == FEASIBLE and pb.verify(pr, x):
                    feas[i] = True
                    wit[i] = _coords(pb.frame(pr.tag[1]), x)
                    self.stats["bnb_feasible"] += 1
                elif st == INFEASIBLE:
                    self.stats["bnb_infeasible"] += 1
                    if self.certify_all:  # the B&B domain is bounded: confirm on the plane
                        leftover.append(i)
                        continue
                else:
                    leftover.append(i)
            bnb_infeasible = {i for i, st in zip(todo, status, strict=True) if st == INFEASIBLE}
            self.stats["bnb_undecided"] += len(set(leftover) - bnb_infeasible)
            if refine is not None:
                und = np.zeros(n, bool)
                und[[i for i in leftover if i not in bnb_infeasible]] = True
                refuted = refine(feas.copy(), und) & und
                self.stats["pc_infeasible"] += int(refuted.sum())
                for i in np.flatnonzero(refuted):
                    self.undecided.append({"problem": name, "tag": _tag(problems[i].tag),
                                           "bnb": "undecided",
                                           "resolved": "path-consistency-infeasible"})
                if self.certify_all:  # confirm with z3 like the B&B refutations
                    bnb_infeasible |= set(np.flatnonzero(refuted).tolist())
                else:
                    leftover = [i for i in leftover if not refuted[i]]
            t0 = time.perf_counter()
            verdicts = certify.decide_many([problems[i].constraints for i in leftover],
                                           progress=self.progress, desc=f"{name} (z3)")
            for i, (verdict, x) in zip(leftover, verdicts, strict=True):
                pr = problems[i]
                if i in bnb_infeasible:
                    if verdict == certify.UNSAT:
                        self.stats["z3_confirmed_infeasible"] += 1
                        continue
                    if verdict == certify.SAT:  # an UNKNOWN is counted as "open" below
                        self.stats["z3_overturned"] += 1
                rec = {"problem": name, "tag": _tag(pr.tag),
                       "bnb": "infeasible-in-box" if i in bnb_infeasible else "undecided",
                       "resolved": f"z3-{verdict}"}
                if verdict == certify.SAT:
                    feas[i] = True
                    wit[i] = _coords(pb.frame(pr.tag[1]), x)
                    rec["exact_witness"] = pb.verify(pr, x)
                    self.stats["z3_sat"] += 1
                elif verdict == certify.UNSAT:
                    self.stats["z3_unsat"] += 1
                else:
                    self.stats["open"] += 1
                    rec["resolved"] = "open"
                self.undecided.append(rec)
            self.stats["z3_seconds"] += time.perf_counter() - t0
        return feas, wit


def _mirror_plan(keys: list[tuple], known: dict[int, list], sigma, unordered: bool) -> tuple:
    """The mirror-pair plan of :func:`_run_mirrored`.

    Returns (representative of each key, the representatives, their positions, known witnesses
    of the representatives).
    """
    rep = symmetry.representatives(keys, sigma, unordered)
    reps = [n for n in range(len(keys)) if rep[n] == n]
    pos = {n: r for r, n in enumerate(reps)}
    known_r: dict[int, list] = {}
    for n, w in sorted(known.items(), key=lambda kv: kv[0] == rep[kv[0]]):  # own last
        known_r[pos[rep[n]]] = w if n == rep[n] else symmetry.mirror_witness(w)
    return rep, reps, pos, known_r


def _run_mirrored(dec: _Decider, name: str, keys: list[tuple], make, tag,
                  known: dict[int, list], sigma: list[int] | None, *, unordered: bool = False,
                  refine=None) -> tuple:
    """:meth:`_Decider.run` on one problem of each mirror pair (:mod:`.symmetry`).

    The other takes the verdict and the reflected witness (and a copy of any certification record).
    ``make(n)`` builds problem n (only representatives are built), ``tag(n)`` its tag.
    """
    rep, reps, pos, known_r = _mirror_plan(keys, known, sigma, unordered)
    full_of = np.array([pos[rep[n]] for n in range(len(keys))], np.int64)
    refine_r = None
    if refine is not None:
        def refine_r(feas_r, und_r):
            refuted = refine(feas_r[full_of], und_r[full_of])
            out = np.zeros(len(reps), bool)
            np.logical_or.at(out, full_of, refuted)
            return out
    n_rec = len(dec.undecided)
    feas_r, wit_r = dec.run(name, [make(n) for n in reps], known_r, refine=refine_r)
    dec.stats["mirror_copies"] += len(keys) - len(reps)
    feas = feas_r[full_of]
    wit = {}
    for n in range(len(keys)):
        w = wit_r.get(full_of[n])
        if w is not None:
            wit[n] = w if n == rep[n] else symmetry.mirror_witness(w)
    recs = {repr(r["tag"]): r for r in dec.undecided[n_rec:]}
    for n in range(len(keys)):
        r = recs.get(repr(_tag(tag(rep[n])))) if n != rep[n] else None
        if r is not None:
            dec.undecided.append({**r, "tag": _tag(tag(n)), "mirror_of": r["tag"]})
    return feas, wit


def _tag(tag) -> list:
    return [t if isinstance(t, str) else list(t) for t in tag]


def _first_rows(key: np.ndarray, base: int) -> np.ndarray:
    """Index of the first occurrence of every distinct row of an int array [N, c].

    Values lie in [0, base); the result is in increasing order of the rows (as base-``base``
    numbers).
    """
    code = np.zeros(len(key), np.int64)
    for col in key.T:
        code = code * base + col
    if base ** key.shape[1] > 1 << 22:  # too many codes for a dense table: sort
        return np.unique(code, return_index=True)[1]
    first = np.full(base ** key.shape[1], len(code))
    np.minimum.at(first, code, np.arange(len(code)))
    return first[first < len(code)]


def _prepass(calc: Calculus, atoms: list, seed: int, n_samples: int):
    """Verified witnesses from sampled (open) or integer-grid (boundary) configurations."""
    if calc.boundary_inclusive:
        cfg = exact.grid_configs(3)
        rel = exact.realised(calc, atoms, cfg)
        config = cfg.__getitem__
    else:
        rel, pts = exact.sampled_realised(calc, atoms, jax.random.PRNGKey(seed), n_samples)

        def config(i):  # only the witnesses' configurations are written out in float64
            return exact.configs_of(pts[i:i + 1])[0]
    unary: dict[tuple, list] = {}
    comp: dict[tuple, list] = {}
    for op in UNARY:
        key = np.stack([rel["abc"], rel[_UNARY_KEY[op]]], 1)
        ok = (key >= 0).all(1)
        first = _first_rows(key[ok], len(atoms))
        for idx in np.flatnonzero(ok)[first]:
            unary[(op, int(key[idx, 0]), int(key[idx, 1]))] = config(idx)
    key = np.stack([rel["abc"], rel["bcd"], rel["abd"]], 1)
    ok = (key >= 0).all(1)
    first = _first_rows(key[ok], len(atoms))
    for idx in np.flatnonzero(ok)[first]:
        comp[tuple(int(v) for v in key[idx])] = config(idx)
    return unary, comp


def _verified(calc, atoms, cfg, pairs) -> bool:
    """Exactly re-verify that configuration cfg realises the given (relation, atom) pairs."""
    A, B, C, D = (tuple(p) for p in cfg)
    pts = {"A": A, "B": B, "C": C, "D": D}
    for (x, y, z), atom in pairs:
        s = exact.exact_signs(calc, pts[x], pts[y], pts[z])
        if s != atoms[atom]:
            return False
    return True


_REL_NAMES = {"left": ("B", "C", "A"), "right": ("C", "A", "B"), "inverse": ("B", "A", "C")}


def _live_atoms(calc, atoms, pre_unary, dec) -> list[int]:
    """The atoms that exist at all (stage 1; pre-pass witnesses are known answers)."""
    single = [pb.Problem(pb.simplify(pb.relation(calc, a, *(pb.frame(a)[x] for x in "ABC"))),
                         ("atom", a)) for a in atoms]
    seen = {k[1] for k in pre_unary}
    known = {}
    for i in range(len(atoms)):
        if i in seen:
            cfg = next(v for k, v in pre_unary.items() if k[1] == i)
            known[i] = [list(map(float, p)) for p in cfg[:3]]
    exists, _ = dec.run("atoms", single, known)
    return [i for i in range(len(atoms)) if exists[i]]


def _build_jobs(calc, atoms, astate, live, pre_unary, pre_comp, box, adjacency_radius) -> dict:
    """Every problem family of the build: ``name → (keys, make(n), tag(n), known, unordered)``.

    ``known`` holds the pre-pass configurations that re-verify exactly (answers without B&B).
    """
    jobs = {}
    for op in UNARY:
        keys, known = [], {}
        for i in live:
            for j in live:
                keys.append((i, j))
                cfg = pre_unary.get((op, i, j))
                if cfg is not None and _verified(calc, atoms, cfg,
                                                 [(("A", "B", "C"), i), (_REL_NAMES[op], j)]):
                    known[len(keys) - 1] = [list(map(float, p)) for p in cfg[:3]]
        jobs[op] = (
            keys,
            lambda n, op=op, keys=keys: pb.unary_problem(calc, op, *(atoms[x] for x in keys[n])),
            lambda n, op=op, keys=keys: (op, *(atoms[x] for x in keys[n])), known, False)
    keys, known = [], {}
    for i in live:
        for j in live:
            for k in live:
                keys.append((i, j, k))
                cfg = pre_comp.get((i, j, k))
                if cfg is not None and _verified(
                        calc, atoms, cfg,
                        [(("A", "B", "C"), i), (("B", "C", "D"), j), (("A", "B", "D"), k)]):
                    known[len(keys) - 1] = [list(map(float, p)) for p in cfg]
    jobs["compose"] = (keys, lambda n, keys=keys: pb.compose_problem(
        calc, *(atoms[x] for x in keys[n]), box),
        lambda n, keys=keys: ("compose", *(atoms[x] for x in keys[n])), known, False)
    nondeg = [i for i in live if isinstance(atoms[i], tuple)]
    if not calc.boundary_inclusive:
        keys = [(a, b) for a in nondeg for b in nondeg if a < b and astate[a] != astate[b]]
        jobs["adjacency"] = (keys, lambda n, keys=keys: pb.adjacency_problem(
            calc, *(atoms[x] for x in keys[n]), adjacency_radius),
            lambda n, keys=keys: ("adjacent", *(atoms[x] for x in keys[n])), {}, True)
    return jobs


def _compose_refiner(calc, atoms, keys, unary_atoms):
    """The path-consistency refutation of compose candidates (None where it does not apply:
    boundary-inclusive calculi and calculi with degenerate atoms)."""
    if calc.boundary_inclusive or not all(isinstance(a, tuple) for a in atoms):
        return None
    na = len(atoms)
    K = np.asarray(keys, np.int64).reshape(-1, 3)

    def refine(feas_full, und_full):
        """Path-consistency refutation, repeated while it removes candidate entries."""
        T = np.zeros((na, na, na), bool)
        T[tuple(K[feas_full | und_full].T)] = True
        refuted = np.zeros(len(K), bool)
        while True:
            idx = np.flatnonzero(und_full & ~refuted)
            r = symmetry.path_consistency_refutes(
                unary_atoms["left"], unary_atoms["right"], unary_atoms["inverse"], T, K[idx])
            if not r.any():
                return refuted
            refuted[idx[r]] = True
            T[tuple(K[idx[r]].T)] = False

    return refine


def build_base(calc: Calculus, *, box: float = 8.0, progress: bool = False, seed: int = 0,
               n_samples: int = 1 << 20, pool: int = 32, max_iters: int = 120,
               adjacency_radius: float = 1e-2, certify_all: bool = False,
               solver=solve) -> dict:
    """Exact tables of a calculus defined by constraints (not a merge).

    The four-stage pipeline is described in docs/tables.md §build.

    Args:
        calc: the constraint-defined calculus.
        box: the branch-and-bound domain |x| ≤ ``box``, with pairwise distances at least
            |AB|/``box``.
        progress: show progress bars.
        seed: seed of the witness pre-pass and the probe points.
        n_samples: random configurations of the witness pre-pass (open calculi).
        pool: the most boxes one problem may hold.
        max_iters: the most branch-and-bound rounds per problem.
        adjacency_radius: radius of the probe disks of the adjacency test.
        certify_all: confirm every refutation with z3 on the whole plane (as for the shipped
            tables), not only the undecided problems.
        solver: decides the branch-and-bound batches (default :func:`.feasibility.solve`; the
            benchmark passes a recording wrapper to time the build's own batches).

    Returns:
        A dict with the ``left``, ``right``, ``inverse`` (``[Q, Q]`` bool), ``compose``
        (``[Q, Q, Q]`` bool) and ``adjacency`` (``[Q, Q]`` bool) tables, the witnesses of every
        present entry, the ``undecided`` problems with their verdicts, build statistics and the
        settings used.
    """
    t_start = time.perf_counter()
    atoms, astate = pb.atoms(calc)
    na, Q = len(atoms), calc.num_states
    dec = _Decider(box, progress, pool, max_iters, certify_all, solver)
    pre_unary, pre_comp = _prepass(calc, atoms, seed, n_samples)
    live = _live_atoms(calc, atoms, pre_unary, dec)
    sigma = symmetry.mirror_atoms(calc, atoms)
    jobs = _build_jobs(calc, atoms, astate, live, pre_unary, pre_comp, box, adjacency_radius)
    # every B&B problem of the build in one batch (the verdicts do not depend on the batching)
    made: dict[tuple, pb.Problem] = {}
    for name, (keys, make, _, known, unordered) in jobs.items():
        _, reps, pos, known_r = _mirror_plan(keys, known, sigma, unordered)
        made.update({(name, n): make(n) for n in reps if pos[n] not in known_r})
    dec.presolve(list(made.values()))

    def decide(name, refine=None):
        keys, make, tag, known, unordered = jobs[name]
        return _run_mirrored(dec, name, keys, lambda n: made.get((name, n)) or make(n), tag,
                             known, sigma, unordered=unordered, refine=refine)

    unary = {op: np.zeros((Q, Q), bool) for op in UNARY}
    unary_atoms = {op: np.zeros((na, na), bool) for op in UNARY}
    unary_wit: dict[str, list] = {}
    for op in UNARY:
        feas, wit = decide(op)
        for n, (i, j) in enumerate(jobs[op][0]):
            if feas[n]:
                unary_atoms[op][i, j] = True
                si, sj = astate[i], astate[j]
                unary[op][si, sj] = True
                unary_wit.setdefault(f"{op}|{calc.states[si]}|{calc.states[sj]}", wit[n][:3])

    compose = np.zeros((Q, Q, Q), bool)
    comp_wit: dict[str, list] = {}
    keys = jobs["compose"][0]
    feas, wit = decide("compose", _compose_refiner(calc, atoms, keys, unary_atoms))
    for n, (i, j, k) in enumerate(keys):
        if feas[n]:
            s = (astate[i], astate[j], astate[k])
            compose[s] = True
            comp_wit.setdefault("|".join(calc.states[x] for x in s), wit[n])

    adjacency = np.zeros((Q, Q), bool)
    if calc.boundary_inclusive:
        nondeg = [i for i in live if isinstance(atoms[i], tuple)]
        adjacency |= _face_adjacency(calc, atoms, astate, nondeg)
    else:
        feas, _ = decide("adjacency")
        for n, (a, b) in enumerate(jobs["adjacency"][0]):
            if feas[n]:
                adjacency[astate[a], astate[b]] = adjacency[astate[b], astate[a]] = True
    if calc.degenerate is not None:
        adjacency[calc.dou, calc.tri] = adjacency[calc.tri, calc.dou] = True

    dec.stats["seconds"] = time.perf_counter() - t_start
    return {
        "left": unary["left"], "right": unary["right"], "inverse": unary["inverse"],
        "compose": compose, "adjacency": adjacency, "unary_witnesses": unary_wit,
        "witnesses": comp_wit, "undecided": dec.undecided, "stats": dec.stats,
        "settings": {"box": box, "ratio_bound": box, "pool": pool, "max_iters": max_iters,
                     "adjacency_radius": adjacency_radius, "prepass_samples": n_samples,
                     "certify_all": certify_all,
                     "seed": seed},
    }


def _face_adjacency(calc, atoms, astate, live) -> np.ndarray:
    """Adjacency of a boundary-inclusive calculus: the face order.

    Relations are neighbours iff one lies in the closure of the other. For an arrangement of lines
    (convex cells) face j lies in the closure of cell i iff j's sign vector is i's with some signs
    set to zero.
    """
    if any(p.terms.get((0, 0, 1)) or p.weighted_degree() > 1 for p in calc.constraints):
        raise NotImplementedError("face adjacency needs line constraints")
    Q = calc.num_states
    adj = np.zeros((Q, Q), bool)

    def below(j, i):  # face j ≤ face i
        return all(sj == 0 or sj == si for sj, si in zip(atoms[j], atoms[i], strict=True))

    for i in live:
        for j in live:
            if i != j and astate[i] != astate[j] and (below(j, i) or below(i, j)):
                adj[astate[i], astate[j]] = True
    return adj


def merge_tables(calc: Calculus, parent: dict) -> dict:
    """Exact tables of a merge: unions over the fine states (witnesses carried over)."""
    M = calc.parent_map
    Q = calc.num_states
    fine = calc.parent.states
    onehot = np.zeros((len(M), Q), bool)
    onehot[np.arange(len(M)), M] = True
    out = {}
    for op in UNARY:
        out[op] = (onehot.T.astype(int) @ parent[op].astype(int) @ onehot.astype(int)) > 0
    comp = np.einsum("ia,jb,kc,ijk->abc", onehot, onehot, onehot, parent["compose"].astype(int))
    out["compose"] = comp > 0
    adj = (onehot.T.astype(int) @ parent["adjacency"].astype(int) @ onehot.astype(int)) > 0
    np.fill_diagonal(adj, False)
    out["adjacency"] = adj

    def relabel(d, n):
        res = {}
        for key, w in d.items():
            parts = key.split("|")
            labs = parts[-n:]
            new = "|".join(parts[:-n] + [calc.states[M[fine.index(x)]] for x in labs])
            res.setdefault(new, w)
        return res

    out["unary_witnesses"] = relabel(parent["unary_witnesses"], 2)
    out["witnesses"] = relabel(parent["witnesses"], 3)
    out["undecided"] = []  # certification lives with the parent's table
    out["stats"] = {"derived_from": calc.parent.name,
                    "parent_undecided_by_bnb": len(parent["undecided"]),
                    "parent_open": sum(u["resolved"] == "open" for u in parent["undecided"])}
    out["settings"] = {"merge_of": calc.parent.name}
    return out


def neighbor_distance(adjacency: np.ndarray) -> np.ndarray:
    """All-pairs shortest path lengths in the conceptual neighbourhood graph (−1 unreachable).

    Breadth-first search from every state, ``scipy.sparse.csgraph.shortest_path`` (unweighted,
    directed as given).

    Args:
        adjacency: ``[Q, Q]`` bool, ``adjacency[i, j]`` = an edge i → j.

    Returns:
        ``[Q, Q]`` int32 hop counts, ``-1`` where j cannot be reached from i.

    >>> neighbor_distance(np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]], bool)).tolist()
    [[0, 1, -1], [1, 0, -1], [-1, -1, 0]]
    """
    from scipy.sparse import csr_array
    from scipy.sparse.csgraph import shortest_path

    adj = np.asarray(adjacency, bool)
    if adj.ndim != 2 or adj.shape[0] != adj.shape[1]:
        raise ValueError(f"adjacency must be a square (Q, Q) matrix, got shape {adj.shape}")
    d = shortest_path(csr_array(adj.astype(np.int8)), method="D", directed=True,
                      unweighted=True)
    return np.where(np.isfinite(d), d, -1).astype(np.int32)


__all__ = ["build_base", "merge_tables", "neighbor_distance"]
