"""Multi-process studies on jax.distributed: 2 local processes give the 1-process results bit
for bit; bad process counts/ids, an unreachable coordinator, missing peers and differing
configs are refused with clear errors in bounded time."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pqrm_jax.cli import main
from pqrm_jax.studies import distributed

ROOT = Path(__file__).resolve().parent.parent

_DRIVER = """
import sys
from pathlib import Path
from pqrm_jax.studies import distributed, padgett_mc as P
out, n, pid, port = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
hb = int(sys.argv[5]) if len(sys.argv) > 5 else 60
cluster = distributed.initialize(f"127.0.0.1:{port}", n, pid, timeout_s=60, heartbeat_s=hb)
cfg = P.Config(runs=4, levels=2, num_samples=8, num_landmarks=4, chunk_runs=2,
               representations=("edc",))
P.run_study(cfg, Path(out), quiet=True, cluster=cluster)
print("done", cluster.process_id, cluster.num_processes)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    return dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")


def _launch(argvs: list[list[str]], timeout: float = 300) -> list[subprocess.CompletedProcess]:
    procs = [subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=_env(), cwd=ROOT) for a in argvs]
    out = []
    for p in procs:
        try:
            so, se = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            raise
        out.append(subprocess.CompletedProcess(p.args, p.returncode, so, se))
    return out


def _start_and_kill(argv_of, ready, *, wait_s: float, give_up_s: float,
                    poll_s: float = 0.2) -> None:
    """Start processes 1 and 0 (``argv_of(i)``); once ``ready()`` kill process 1 and check that
    process 0 gives up with an error within ``give_up_s`` (no hang)."""
    procs = [subprocess.Popen(argv_of(i), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=_env(), cwd=ROOT) for i in (1, 0)]
    deadline = time.monotonic() + wait_s
    while not ready():
        assert time.monotonic() < deadline and procs[1].poll() is None, \
            procs[1].communicate()[1][-2000:] if procs[1].poll() is not None else "timeout"
        time.sleep(poll_s)
    procs[0].kill()
    t_kill = time.monotonic()
    procs[1].communicate(timeout=give_up_s + 60)  # process 0 must give up, not hang
    procs[0].communicate()
    assert procs[1].returncode != 0 and time.monotonic() - t_kill < give_up_s


def _same_results(a: Path, b: Path) -> int:
    names = sorted(p.name for p in a.glob("level_*.npz"))
    assert names and names == sorted(p.name for p in b.glob("level_*.npz"))
    for name in names:
        x, y = np.load(a / name), np.load(b / name)
        assert sorted(x.files) == sorted(y.files)
        for k in x.files:
            np.testing.assert_array_equal(x[k], y[k], err_msg=f"{name}:{k}")
    for f in ("levels.jsonl", "results.csv", "config.json"):
        assert (a / f).read_text() == (b / f).read_text(), f
    return len(names)


def _driver_one_and_two(one: Path, two: Path, driver: str = _DRIVER,
                        timeout: float = 300) -> list[subprocess.CompletedProcess]:
    """A study driver (default: the padgett one) as 1 process into ``one`` and as 2 processes
    into ``two``, at once; every process must succeed."""
    port = str(free_port())
    rs = _launch([[sys.executable, "-c", driver, str(one), "1", "0", "0"]]
                 + [[sys.executable, "-c", driver, str(two), "2", str(i), port]
                    for i in (1, 0)], timeout=timeout)
    for r in rs:
        assert r.returncode == 0, r.stderr[-2000:]
    return rs


def test_two_processes_bit_identical_to_one(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    # the one-process reference runs beside the two cooperating processes (wall time)
    last = [r.stdout.strip().splitlines()[-1] for r in _driver_one_and_two(one, two)]
    assert last == ["done 0 1", "done 1 2", "done 0 2"]
    assert _same_results(one, two) == 6
    # only process 0 wrote: the directory holds exactly the files of a one-process run
    assert sorted(p.name for p in one.iterdir()) == sorted(p.name for p in two.iterdir())


def test_bad_process_count_id_and_address_are_refused_before_starting():
    with pytest.raises(ValueError, match="out of range for 2 processes"):
        distributed.initialize("127.0.0.1:1234", 2, 2, env={})
    with pytest.raises(ValueError, match="out of range"):
        distributed.initialize("127.0.0.1:1234", 2, -1, env={})
    with pytest.raises(ValueError, match="process count must be an integer >= 1"):
        distributed.initialize("127.0.0.1:1234", 0, 0, env={})
    with pytest.raises(ValueError, match="HOST:PORT"):
        distributed.initialize("localhost", 2, 1, env={})
    with pytest.raises(ValueError, match="port in 1..65535"):
        distributed.initialize("127.0.0.1:70000", 2, 1, env={})
    with pytest.raises(ValueError, match="needs coordinator address"):
        distributed.initialize(None, 2, 1, env={})
    with pytest.raises(ValueError, match=r"\$JAX_NUM_PROCESSES must be an integer"):
        distributed.initialize(env={"JAX_NUM_PROCESSES": "two"})
    # the environment is read like the flags
    with pytest.raises(ValueError, match="out of range for 3 processes"):
        distributed.initialize(env={"JAX_COORDINATOR_ADDRESS": "h:1", "JAX_NUM_PROCESSES": "3",
                                    "JAX_PROCESS_ID": "3"})
    assert distributed.initialize(env={}) == distributed.Cluster(0, 1, None)


def test_unreachable_coordinator_and_missing_peer_fail_in_bounded_time():
    port = free_port()
    t0 = time.perf_counter()
    with pytest.raises(distributed.DistributedError, match="could not reach the coordinator"):
        distributed.initialize(f"127.0.0.1:{port}", 2, 1, timeout_s=2, env={})
    with pytest.raises(distributed.DistributedError, match=r"processes \[1\] of 2 never"):
        distributed.initialize(f"127.0.0.1:{port}", 2, 0, timeout_s=2, env={})
    assert time.perf_counter() - t0 < 10


def test_cli_errors_are_one_line(tmp_path, capsys):
    argv = ["study", "padgett-mc", "--out", str(tmp_path / "o"), "--quiet"]
    assert main([*argv, "--coordinator", "127.0.0.1:1", "--processes", "2",
                 "--process-id", "7"]) == 2
    assert "process id 7 is out of range for 2 processes" in capsys.readouterr().err
    assert main([*argv, "--coordinator", f"127.0.0.1:{free_port()}", "--processes", "2",
                 "--process-id", "1", "--init-timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pqrm-jax: error: process 1 could not reach") and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_processes_with_different_configs_are_refused(tmp_path):
    port = str(free_port())
    base = [sys.executable, "-m", "pqrm_jax.cli", "study", "padgett-mc", "--out",
            str(tmp_path / "o"), "--quiet", "--runs", "2", "--levels", "2",
            "--coordinator", f"127.0.0.1:{port}", "--processes", "2"]
    rs = _launch([[*base, "--samples", "8", "--process-id", "1"],
                  [*base, "--samples", "16", "--process-id", "0"]], timeout=120)
    for r in rs:
        assert r.returncode == 2, r.stderr[-2000:]
        assert "processes [1] were started with a different padgett-mc config" in r.stderr
    assert not (tmp_path / "o").exists()  # refused before anything was written


_SLURM_DRIVER = """
import numpy as np
from pqrm_jax.studies import distributed as d
c = d.initialize(timeout_s=30)
print(c.process_id, c.num_processes, d.gather(np.array([c.process_id * 7]), c).ravel().tolist())

def fn(x):  # item 3 (round 2, process 1) fails
    if x == 3:
        raise ValueError("bad unit 3")
    return {"x": x}

try:
    print([r["x"] for _, r in d.map_units(fn, [0, 1, 2, 3, 4], c)])
except d.DistributedError as exc:
    print("refused:", exc)
"""


def test_slurm_environment_is_detected_and_a_unit_failure_reaches_every_process():
    """Two tasks with the variables ``srun`` sets (faked on localhost): JAX's Slurm detection
    gives the coordinator (port from the job id), ours the count and the ids. In the same
    launch, item 3 of a ``map_units`` fails on process 1: both processes stop with its error,
    none waits for a result that never comes."""
    for job in range(1000, 5096):  # JAX takes port 61440 + job % 4096
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", 61440 + job % 4096))
                break
            except OSError:
                continue
    envs = [dict(_env(), SLURM_JOB_ID=str(job), SLURM_STEP_NODELIST="localhost",
                 SLURM_NTASKS="2", SLURM_PROCID=str(i), SLURM_LOCALID=str(i)) for i in (0, 1)]
    procs = [subprocess.Popen([sys.executable, "-c", _SLURM_DRIVER], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=e, cwd=ROOT) for e in envs]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (_, se) in zip(procs, outs, strict=True):
        assert p.returncode == 0, se[-2000:]
    assert [so.strip().splitlines()[-2] for so, _ in outs] == ["0 2 [0, 7]", "1 2 [0, 7]"]
    for so, _ in outs:
        assert so.strip().splitlines()[-1] == (
            "refused: process 1 failed on item 3: ValueError: bad unit 3")
    # a batch script outside srun (no step node list) is one process
    assert distributed.initialize(env={"SLURM_JOB_ID": "1", "SLURM_NTASKS": "4"}).num_processes == 1


@pytest.mark.slow
def test_cli_two_processes_equal_one_full_representations(tmp_path):
    """The real command line, all six representations, 2 processes vs 1."""
    args = ["study", "padgett-mc", "--runs", "8", "--levels", "2", "--samples", "16",
            "--landmarks", "5", "--chunk", "4", "--quiet"]
    py = [sys.executable, "-m", "pqrm_jax.cli"]
    (r1,) = _launch([[*py, *args, "--out", str(tmp_path / "one")]], timeout=600)
    port = str(free_port())
    two = [*py, *args, "--out", str(tmp_path / "two"), "--coordinator", f"127.0.0.1:{port}",
           "--processes", "2"]
    rs = _launch([[*two, "--process-id", "1"], [*two, "--process-id", "0"]], timeout=600)
    for r in (r1, *rs):
        assert r.returncode == 0, r.stderr[-2000:]
    assert _same_results(tmp_path / "one", tmp_path / "two") == 6
    assert (tmp_path / "two" / "report.md").exists()


@pytest.mark.slow
def test_killed_process_then_resume_gives_the_one_process_results(tmp_path):
    """Kill process 1 after the first level is written: process 0 stops within the heartbeat
    timeout (no hang); re-running both processes resumes and ends with the 1-process files."""
    one, two = tmp_path / "one", tmp_path / "two"
    port = str(free_port())
    _start_and_kill(lambda i: [sys.executable, "-c", _DRIVER, str(two), "2", str(i), port, "5"],
                    (two / "level_00.npz").exists, wait_s=300, give_up_s=90)
    done = len(list(two.glob("level_*.npz")))
    assert 1 <= done < 6
    _driver_one_and_two(one, two)
    assert _same_results(one, two) == 6


# --------------------------------------------------------------------------------------
# the other Monte Carlo studies on distributed.map_units: 2 processes vs 1
# --------------------------------------------------------------------------------------

_TIMING = ("wall", "update_time", "seconds", "_time", "time_", "explore_s", "map_s",
           "setting_s", "reloc_s")  # measured, differ per run


def _timed(name: str) -> bool:
    return any(t in name for t in _TIMING)


def _drop_timing(obj):
    if isinstance(obj, dict):
        return {k: _drop_timing(v) for k, v in obj.items() if not _timed(k)}
    if isinstance(obj, list):
        return [_drop_timing(v) for v in obj]
    return obj


def _same_study_files(a: Path, b: Path) -> int:
    """Every stored record of ``a`` equals ``b``'s bit for bit, measured times excepted."""
    import json

    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file()
                   and not p.name.startswith("."))
    assert names == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file()
                           and not p.name.startswith("."))
    compared = 0
    for name in names:
        x, y = a / name, b / name
        if name.endswith(".npz"):
            nx, ny = np.load(x), np.load(y)
            assert sorted(nx.files) == sorted(ny.files), name
            for k in nx.files:
                if not _timed(k):
                    np.testing.assert_array_equal(nx[k], ny[k], err_msg=f"{name}:{k}")
        elif name.endswith(".jsonl"):
            lx, ly = x.read_text().splitlines(), y.read_text().splitlines()
            assert [_drop_timing(json.loads(v)) for v in lx] == \
                [_drop_timing(json.loads(v)) for v in ly], name
        elif name.endswith(".json"):
            assert _drop_timing(json.loads(x.read_text())) == \
                _drop_timing(json.loads(y.read_text())), name
        elif name.endswith(".csv"):
            assert [r for r in x.read_text().splitlines() if not _timed(r)] == \
                [r for r in y.read_text().splitlines() if not _timed(r)], name
        else:
            continue  # report.md and figures show the measured times too
        compared += 1
    return compared


def _one_vs_two(tmp_path, argv: list[str], timeout: float = 600) -> tuple[Path, Path]:
    py = [sys.executable, "-m", "pqrm_jax.cli", *argv]
    port = str(free_port())
    two = [*py, "--out", str(tmp_path / "two"), "--coordinator", f"127.0.0.1:{port}",
           "--processes", "2"]
    rs = _launch([[*py, "--out", str(tmp_path / "one")], [*two, "--process-id", "1"],
                  [*two, "--process-id", "0"]], timeout=timeout)
    for r in rs:
        assert r.returncode == 0, r.stderr[-2000:]
    return tmp_path / "one", tmp_path / "two"


@pytest.mark.slow
def test_serge_two_processes_equal_one(tmp_path):
    """Slow (3 processes, ~22 CPU-s): the default suite keeps padgett-mc's 2-vs-1 bit
    identity and the shared mechanism's kill-and-resume and failure tests."""
    one, two = _one_vs_two(tmp_path, ["study", "serge", "--reduced", "--datasets",
                                      "well_separated", "--grid", "16", "--trials", "4"])
    assert _same_study_files(one, two) == 4  # config, study marker, results.jsonl and .csv
    assert len((two / "results.jsonl").read_text().splitlines()) == 18
    assert (two / "report.md").exists()


@pytest.mark.slow
def test_mcclelland_mc_two_processes_equal_one(tmp_path):
    """3 (n, run) units per n: process 0 takes units 0 and 2 of each round pair."""
    one, two = _one_vs_two(tmp_path, ["study", "mcclelland-mc", "--reduced", "--runs", "3",
                                      "--images", "5", "--ns", "6", "--exact-sample", "0",
                                      "--no-progress"])
    # 3 runs + their times, config, marker, summary, timing, results.csv
    assert _same_study_files(one, two) == 11
    assert (two / "report.md").exists()


_MARS_DRIVER = """
import sys
from pathlib import Path
from pqrm_jax.studies import distributed, mars_yard as M
out, n, pid, port = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
cluster = distributed.initialize(f"127.0.0.1:{port}", n, pid, timeout_s=60)
cfg = M.Config(landmarks=10, n=6, images=30, nav_pairs=4, nav_steps=100, traverses=3,
               snapshots=(1, 30))
M.run_study(cfg, Path(out), quiet=True, cluster=cluster)
"""


@pytest.mark.slow
def test_mars_yard_two_processes_equal_one(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    _driver_one_and_two(one, two, _MARS_DRIVER, timeout=600)
    assert _same_study_files(one, two) == 9  # 3 traverses + times, config, marker, results.csv
    assert (two / "fig11.png").exists()  # traverse 0's figures, drawn by process 0


@pytest.mark.slow
def test_fdc_design_and_compositions_heldout_two_processes_equal_one(tmp_path):
    one, two = _one_vs_two(tmp_path / "fdc", ["study", "fdc-design", "--reduced",
                                              "--no-progress"])
    assert _same_study_files(one, two) == 5  # design, searches, config, marker, results.csv
    one, two = _one_vs_two(tmp_path / "ho", [
        "study", "compositions-heldout", "--landmarks", "6", "--runs", "2", "--samples", "32",
        "--fractions", "0.25", "0.5", "--sigmas", "5", "--rounds", "1"])
    assert _same_study_files(one, two) == 5  # results, cells, config, marker, results.csv


_MCC_DRIVER = """
import sys
from pathlib import Path
from pqrm_jax.studies import distributed, mcclelland_mc as M
out, n, pid, port = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
cluster = distributed.initialize(f"127.0.0.1:{port}", n, pid, timeout_s=60, heartbeat_s=5)
cfg = M.Config(runs=4, images=5, ns=(6, 8), timed_runs=0, exact_sample=0)
M.run_study(cfg, Path(out), quiet=True, cluster=cluster)
print("done", cluster.process_id)
"""


@pytest.mark.slow
def test_mcclelland_mc_killed_process_then_resume(tmp_path):
    """Kill process 1 once the first round is written: process 0 stops within the heartbeat
    (no hang); re-running both resumes from the written units and ends with the 1-process
    records (measured times excepted)."""
    one, two = tmp_path / "one", tmp_path / "two"
    port = str(free_port())
    _start_and_kill(lambda i: [sys.executable, "-c", _MCC_DRIVER, str(two), "2", str(i), port],
                    lambda: bool(list(two.glob("runs/n*_r*.npz"))), wait_s=300, give_up_s=90)
    written = {p.name for p in (two / "runs").glob("n*_r*.npz")}
    assert 1 <= len(written) < 8
    _driver_one_and_two(one, two, _MCC_DRIVER)
    assert _same_study_files(one, two) == 18  # 8 runs + their times, config, marker


_UNITS_DRIVER = """
import sys, time
from pqrm_jax.studies import distributed as d
from pqrm_jax.studies.store import Store
out, pid, port = sys.argv[1], int(sys.argv[2]), sys.argv[3]
c = d.initialize(f"127.0.0.1:{port}", 2, pid, timeout_s=60, heartbeat_s=5)
st = None

def left():  # process 0: open the store, the units not written yet
    global st
    st = Store.open(out, "units-demo", {"items": 6})
    return [st.read_json(f"units/u{i}.json", ("x", "sq")) is None for i in range(6)]

todo = [i for i, m in enumerate(d.decide(c, 6, left)) if m]

def fn(i):
    time.sleep(1.0)
    return {"x": i, "sq": i * i}

for j, r in d.map_units(fn, todo, c):
    if st is not None:
        st.write_json(f"units/u{todo[j]}.json", r)
print("done", c.process_id, todo)
"""


def test_killed_process_then_resume_on_the_shared_mechanism(tmp_path):
    """The mechanism every study shares (process 0 opens the store and decides what is left,
    ``map_units`` rounds, process 0 writes each unit): kill process 1 once a unit is written;
    process 0 stops within the heartbeat (no hang); both re-run compute only the units left,
    keep the written ones untouched and end with every unit."""
    out = tmp_path / "o"
    port = str(free_port())
    _start_and_kill(lambda i: [sys.executable, "-c", _UNITS_DRIVER, str(out), str(i), port],
                    lambda: bool(list(out.glob("units/u*.json"))), wait_s=120, give_up_s=45,
                    poll_s=0.1)
    written = {p.name: p.stat().st_mtime_ns for p in out.glob("units/u*.json")}
    assert 1 <= len(written) < 6
    port = str(free_port())
    rs = _launch([[sys.executable, "-c", _UNITS_DRIVER, str(out), str(i), port]
                  for i in (1, 0)], timeout=120)
    for r in rs:
        assert r.returncode == 0, r.stderr[-2000:]
    left = [i for i in range(6) if f"u{i}.json" not in written]
    assert [r.stdout.strip().splitlines()[-1] for r in rs] == [f"done {p} {left}"
                                                               for p in (1, 0)]
    import json

    assert [json.loads((out / "units" / f"u{i}.json").read_text()) for i in range(6)] == \
        [{"x": i, "sq": i * i} for i in range(6)]
    assert {n: (out / "units" / n).stat().st_mtime_ns for n in written} == written


@pytest.mark.slow
def test_hssh_localization_two_processes_equal_one(tmp_path):
    """6 (run, model) units in rounds of 2; process 0 writes each unit file."""
    one, two = _one_vs_two(tmp_path, ["study", "hssh-localization", "--steps", "3"])
    assert _same_study_files(one, two) == 9  # 6 units, config, marker, results.csv
    assert len(list((two / "units").glob("*.json"))) == 6
    assert (two / "report.md").exists() and (two / "best_likelihood.png").exists()


@pytest.mark.slow
def test_hssh_maps_two_processes_equal_one(tmp_path):
    """2 worlds, 2 office seeds and 1 simulator world in rounds of 2; process 0 writes."""
    one, two = _one_vs_two(tmp_path, ["study", "hssh-maps", "--reduced", "--worlds", "2",
                                      "--no-progress"])
    # worlds/office/sim.jsonl, config, marker, results.csv
    assert _same_study_files(one, two) == 6
    assert len((two / "worlds.jsonl").read_text().splitlines()) == 2
    for f in ("report.md", "sim_map.png", "tree_size.png"):
        assert (two / f).exists()


@pytest.mark.slow
def test_qlink_two_processes_equal_one(tmp_path):
    """Two worlds, one per process: each builds its map and drives its trials units."""
    one, two = _one_vs_two(tmp_path, ["study", "qlink", "--reduced", "--worlds", "0", "1",
                                      "--max-pairs", "8", "--no-progress"])
    n_units = len(list((one / "trials").glob("*.csv")))
    assert n_units == 2 * 5  # b2: R, 0.8R, occ 0.5 m; b1: R, 0.8R
    # 2 world arrays and summaries, the units, trials.csv, config, marker, results.csv
    assert _same_study_files(one, two) == 4 + n_units + 4
    assert (two / "report.md").exists()


# --------------------------------------------------------------------------------------
# kill one process of a multi-process study, then resume: qlink, hssh-maps, hssh-localization
# --------------------------------------------------------------------------------------

def _kill_then_resume(tmp_path, argv: list[str], written, total: int,
                      timeout: float = 900) -> tuple[Path, Path]:
    """Run ``pqrm-jax <argv>`` as 2 processes into ``two``; once ``written(two)`` (units on
    disk) is >= 1 kill process 1: process 0 must stop (no hang, the CLI's 60 s heartbeat
    bounds it). Then re-run both beside a 1-process run into ``one``; returns (one, two)."""
    py = [sys.executable, "-m", "pqrm_jax.cli", *argv]
    two = tmp_path / "two"
    port = str(free_port())
    cmd = [*py, "--out", str(two), "--coordinator", f"127.0.0.1:{port}", "--processes", "2"]
    _start_and_kill(lambda i: [*cmd, "--process-id", str(i)],
                    lambda: two.exists() and written(two) >= 1, wait_s=timeout, give_up_s=180)
    done = written(two)
    assert 1 <= done < total, done
    one, two = _one_vs_two(tmp_path, argv, timeout=timeout)
    assert written(two) == total
    return one, two


@pytest.mark.slow
def test_qlink_killed_process_then_resume(tmp_path):
    """3 worlds in rounds of 2: process 1 is killed once round 1's worlds are written; the
    resumed run computes world 2 only and stores the 1-process records."""
    one, two = _kill_then_resume(
        tmp_path, ["study", "qlink", "--reduced", "--worlds", "0", "1", "2", "--max-pairs",
                   "8", "--no-progress"], lambda d: len(list(d.glob("world_*.json"))), 3)
    assert _same_study_files(one, two) == 6 + 15 + 4  # 3 worlds x (npz, json, 5 units), ...


def _records(d: Path) -> int:
    return sum(len(p.read_text().splitlines()) for p in d.glob("*.jsonl"))


@pytest.mark.slow
def test_hssh_maps_killed_process_then_resume(tmp_path):
    """5 units (1 simulator world, 2 worlds, 2 office seeds) in rounds of 2."""
    one, two = _kill_then_resume(
        tmp_path, ["study", "hssh-maps", "--reduced", "--worlds", "2", "--no-progress"],
        _records, 5)
    assert _same_study_files(one, two) == 6


@pytest.mark.slow
def test_hssh_localization_killed_process_then_resume(tmp_path):
    """6 (run, model) units in rounds of 2."""
    one, two = _kill_then_resume(
        tmp_path, ["study", "hssh-localization", "--steps", "3"],
        lambda d: len(list(d.glob("units/*.json"))), 6)
    assert _same_study_files(one, two) == 9
