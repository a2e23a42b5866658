"""A process of a multi-process run dies: the others end within a bounded time with exit
code 2 and one line naming the process that died (issue 29 item 3), instead of a gloo stack
and exit 134 or a wait in a collective."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

_DRIVER = """
import sys, time
from pqrm_jax.studies import distributed as d
pid, n, port = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
c = d.initialize(f"127.0.0.1:{port}", n, pid, timeout_s=60, heartbeat_s=300)

def fn(i):
    time.sleep(0.3)
    return {"x": i}

for j, r in d.map_units(fn, list(range(10_000)), c):
    print("unit", j, flush=True)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("victim", [2, 0])
def test_a_dead_process_ends_the_others_with_exit_2_naming_it(victim):
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    port = str(_free_port())
    procs = {i: subprocess.Popen([sys.executable, "-c", _DRIVER, str(i), "3", port],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 env=env, cwd=ROOT) for i in (1, 2, 0)}
    try:
        for line in procs[1].stdout:  # the run is under way (collectives every round)
            if line.startswith("unit 6"):
                break
        procs[victim].send_signal(signal.SIGKILL)
        t0 = time.monotonic()
        for i, p in procs.items():
            if i == victim:
                p.wait(60)
                continue
            _, err = p.communicate(timeout=120)  # bounded: no wait in a collective
            assert p.returncode == 2, (i, p.returncode, err[-2000:])
            assert f"pqrm-jax: error: process {victim} of 3 died" in err, err[-2000:]
            assert "Traceback" not in err
        assert time.monotonic() - t0 < 120
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()


_HSSH_PLUS = """
import sys
from pqrm_jax.studies import distributed as d, hssh_plus as H
pid, port = int(sys.argv[1]), sys.argv[2]
c = d.initialize(f"127.0.0.1:{port}", 2, pid, timeout_s=60)

def unit(side, rot, cfg):
    if side == 3:
        raise ValueError(f"bad unit {side}")
    return [{"side": side, "rot": rot}]

H.run_unit = unit

class St:
    def write_json(self, name, obj):
        print("wrote", name, flush=True)

try:
    H._compute([(1, 0.0), (2, 0.0), (3, 0.0), (4, 0.0)], {}, c, St() if c.is_main else None)
except d.DistributedError as exc:
    print("refused:", exc, flush=True)
    d.finish(True)
"""


def test_hssh_plus_split_exchanges_errors():
    """hssh-plus's multi-process split is ``map_units``: a unit failing on process 0 (unit 3
    is item 2, process 0's in round 1) ends both processes with its message, none waits."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    port = str(_free_port())
    procs = [subprocess.Popen([sys.executable, "-c", _HSSH_PLUS, str(i), port],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env, cwd=ROOT) for i in (1, 0)]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (so, se) in zip(procs, outs, strict=True):
        assert p.returncode == 0, se[-2000:]
        assert "refused: process 0 failed on item 2: ValueError: bad unit 3" in so, so
    assert "wrote" in outs[1][0]  # process 0 wrote round 0's units before the failure


_MAP_CHUNKS = """
import sys
import numpy as np
from pqrm_jax.studies import distributed as d
pid, port = int(sys.argv[1]), sys.argv[2]
c = d.initialize(f"127.0.0.1:{port}", 2, pid, timeout_s=60)
for n in (0, 1, 2, 3, 5):  # fewer items than processes, odd counts: padded, reordered
    seen = []
    res = d.map_chunks(lambda i: {"a": np.full(3, i * i, np.int64), "b": np.float32(i) / 3},
                       n, c, done=lambda i, r: seen.append(i))
    assert [int(r["a"][0]) for r in res] == [i * i for i in range(n)], (n, res)
    assert [r["b"] for r in res] == [np.float32(i) / 3 for i in range(n)]  # bits kept
    assert seen == list(range(pid, n, 2)), (n, seen)  # own items only, not the padding
print("orders ok", flush=True)

def fn(i):
    if i == 3:
        raise ValueError(f"bad chunk {i}")
    return np.zeros(2)

try:
    d.map_chunks(fn, 5, c)
except d.DistributedError as exc:
    print("refused:", exc, flush=True)
except ValueError as exc:
    print("own:", exc, flush=True)
d.finish(True)
"""


def test_map_chunks_orders_pads_and_exchanges_errors():
    """The one array splitter over processes (``distributed.map_chunks``): results in item
    order on both processes whatever the count (0, fewer than processes, odd), ``done`` only
    for a process's own items, and a chunk failing on process 1 (item 3) ends both: process 1
    raises its own error, process 0 a DistributedError naming process 1 — none waits in the
    gather (the hand splits of padgett-mc and qbsp it replaces had no exchange)."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    port = str(_free_port())
    procs = [subprocess.Popen([sys.executable, "-c", _MAP_CHUNKS, str(i), port],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env, cwd=ROOT) for i in (1, 0)]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (so, se) in zip(procs, outs, strict=True):
        assert p.returncode == 0, se[-2000:]
        assert "orders ok" in so, so
    assert "own: bad chunk 3" in outs[0][0]
    assert ("refused: process 1 failed on its share of the chunks: ValueError: bad chunk 3"
            in outs[1][0]), outs[1][0]
