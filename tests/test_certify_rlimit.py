"""z3 decisions never depend on the machine's load (issue 29 item 4): the table certifier and
the camera oracle bound z3 by its deterministic resource counter (``rlimit``), never by a
wall-clock timeout; an exhausted limit is ``UNKNOWN``, counted, and the same on a busy and on a
quiet machine."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import z3

from pqrm_jax import calculi
from pqrm_jax.nlsat import first_tactic
from pqrm_jax.qrm import camera_oracle
from pqrm_jax.tables import certify
from pqrm_jax.tables import problems as pb


def _problems(n=24, seed=5):
    return [pr.constraints for pr in pb.random_compose_problems(calculi.get("edc"), n, seed=seed)]


def _cost(text: str) -> int:
    """z3's resource count of one decision (the counter is global: the difference)."""
    s = first_tactic().solver()
    before = s.statistics().get_key_value("rlimit count") \
        if "rlimit count" in s.statistics().keys() else 0
    s.from_string(text)
    s.check()
    return s.statistics().get_key_value("rlimit count") - before


def test_no_wall_clock_timeout_is_set(monkeypatch):
    seen = []
    real = z3.Solver.set

    def spy(self, *args, **kw):
        seen.append(args[0] if args else next(iter(kw)))
        return real(self, *args, **kw)

    monkeypatch.setattr(z3.Solver, "set", spy)
    certify.decide(_problems(1)[0])
    assert "rlimit" in seen and "timeout" not in seen


class _Busy:
    """Processes that keep every core busy (the 'slowed machine')."""

    def __enter__(self):
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                      for _ in range(3)]
        return self

    def __exit__(self, *exc):
        for p in self.procs:
            p.kill()
            p.wait()


def test_a_decision_does_not_change_on_a_slowed_machine():
    """At the very edge of the limit (a few units below / at a problem's own cost) the verdict
    is UNKNOWN / decided, and exactly so again while the CPU is busy; the default limit
    decides everything. A wall-clock limit at the edge would flip with the load."""
    probs = _problems(12)
    texts = [certify.smtlib(c) for c in probs]
    costs = [_cost(t) for t in texts]
    low = [max(cost // 2, 1) for cost in costs]
    quiet_low = [certify.decide(c, lim)[0] for c, lim in zip(probs, low, strict=True)]
    quiet_default = [certify.decide(c)[0] for c in probs]
    with _Busy():
        busy_low = [certify.decide(c, lim)[0] for c, lim in zip(probs, low, strict=True)]
        busy_default = [certify.decide(c)[0] for c in probs]
    assert busy_low == quiet_low and busy_default == quiet_default
    assert certify.UNKNOWN in quiet_low  # the edge is real: half the cost runs out
    assert certify.UNKNOWN not in quiet_default


def test_unknown_is_counted_and_the_pool_agrees():
    probs = _problems(8)
    verdicts = certify.decide_many(probs, workers=1, rlimit=1)
    assert certify.count_unknown(verdicts) == len(probs)
    assert certify.count_unknown(certify.decide_many(probs, workers=1)) == 0
    with pytest.raises(ValueError, match="rlimit"):
        certify.decide(probs[0], rlimit=0)


def test_camera_oracle_treats_an_exhausted_limit_explicitly():
    P = np.array([[2.0, 0.5], [1.0, 3.0], [-4.0, 1.5]])
    bearings = np.arctan2(P[:, 1], P[:, 0])
    with pytest.raises(RuntimeError, match="rlimit=1 exhausted"):
        camera_oracle.oracle_sets(bearings, "edc", rlimit=1)
    assert camera_oracle.oracle_sets(bearings, "edc").tolist() == \
        camera_oracle.oracle_sets(bearings, "edc", rlimit=certify.DEFAULT_RLIMIT).tolist()


def test_the_first_tactic_decides_what_the_simplifier_writes_out_of_cnf():
    """A DCC build problem: z3's simplifier turns ``x0² + x1² > 0`` into
    ``¬(x0 = 0 ∧ x1 = 0)``, which nlsat refuses outside CNF (the build then fell back to the
    slower QF_NRA strategy); the first tactic decides it itself (x1 > 1 and x0² = x1 − x1²)."""
    text = "\n".join([*(f"(declare-fun x{i} () Real)" for i in range(4)),
                      "(assert (> (* 1 x0) 0))", "(assert (> (* 1 x1) 0))",
                      "(assert (> (+ (- 1) (* 1 x1)) 0))",
                      "(assert (> (+ (* 1 x0 x0) (* 1 x1 x1)) 0))",
                      "(assert (= (+ (* 1 x0 x0) (* 1 x1 x1) (* (- 1) x1)) 0))"])
    s = first_tactic().solver()
    s.from_string(text)
    assert s.check() == z3.unsat
    assert certify.decide_smtlib(text, 4) == (certify.UNSAT, None)
