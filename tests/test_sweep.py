"""``pqrm-jax study NAME --sweep``: one study per grid cell, resumable, guarded, with a report.

The machinery is tested on a tiny study that follows the sweep protocol with the real shared
store (fast); padgett-mc itself is swept in the slow tests (a cell equals the direct study run
with the same setting, bit for bit; two processes equal one).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import types
from pathlib import Path

import pytest

from pqrm_jax.cli import main as cli
from pqrm_jax.studies import distributed, sweep
from pqrm_jax.studies.store import Store, StoreError

ROOT = Path(__file__).resolve().parent.parent


@dataclasses.dataclass
class TinyConfig:
    n: int = 3
    scale: float = 1.0
    seed: int = 0
    tags: tuple[str, ...] = ("a",)

    def to_json(self) -> dict:
        return dict(dataclasses.asdict(self), tags=list(self.tags))


def _tiny_study(log: list) -> types.ModuleType:
    """A real (small) study on the shared store: unit u of a cell stores u * scale + seed."""
    mod = types.ModuleType("tiny_study")
    mod.NAME = "tiny"
    mod.Config = TinyConfig

    def configure(argv, overrides=None):
        p = argparse.ArgumentParser(prog="tiny")
        p.add_argument("--out", default="out/tiny")
        p.add_argument("--n", type=int)
        p.add_argument("--seed", type=int, default=0)
        for flag in ("--fresh", "--quiet", "--report-only"):
            p.add_argument(flag, action="store_true")
        distributed.add_arguments(p)
        args = p.parse_args(argv)
        cfg = TinyConfig(seed=args.seed)
        if args.n is not None:
            cfg.n = args.n
        cfg = dataclasses.replace(cfg, **(overrides or {}))
        if cfg.n < 1:
            p.error(f"n must be ≥ 1, got {cfg.n}")
        return cfg, args

    def run_study(cfg, out, *, quiet, cluster):
        with Store.open(out, "tiny", cfg.to_json()) as st:
            rec = st.records("units.jsonl", key=lambda r: r["unit"], required=("unit", "x"))
            for u in range(cfg.n):
                if u not in rec:
                    log.append((out.name, u))
                    rec.add({"unit": u, "x": u * cfg.scale + cfg.seed})

    def main(argv):
        out = Path(argv[argv.index("--out") + 1])
        with Store.open(out, "tiny", None) as st:
            st.write_text("report.md", "tiny report\n")
        return 0

    def sweep_summary(out):
        xs = [json.loads(x)["x"] for x in (out / "units.jsonl").read_text().splitlines()]
        total = sum(xs)
        return {"total": total, "largest": max(xs), "kind": "big" if total > 4 else "small",
                "claims": {"total exceeds 4": "match" if total > 4 else "mismatch"}}

    mod.configure, mod.run_study, mod.main, mod.sweep_summary = (configure, run_study, main,
                                                                  sweep_summary)
    return mod


GRID = ["--sweep", "n=2,4", "--sweep", "scale=0.5,2"]


def test_two_by_two_sweep_runs_resumes_and_reports(tmp_path):
    log: list = []
    tiny = _tiny_study(log)
    out = tmp_path / "sw"
    report = sweep.run(tiny, [*GRID, "--out", str(out), "--quiet"])
    cells = ["n=2,scale=0.5", "n=2,scale=2.0", "n=4,scale=0.5", "n=4,scale=2.0"]
    assert sorted({c for c, _ in log}) == cells and len(log) == 2 + 2 + 4 + 4
    for c in cells:  # each cell a study of its own with the cell's values in its config
        cfg = json.loads((out / c / "config.json").read_text())
        n, s = (x.split("=")[1] for x in c.split(","))
        assert cfg["n"] == int(n) and cfg["scale"] == float(s)
        assert (out / c / "report.md").exists()
    text = report.read_text()
    assert "4 of 4 cells finished" in text
    assert "| total exceeds 4 | 1/4 | `n=4,scale=2.0` |" in text  # totals: 0.5, 2, 3, 12
    assert "`n=4,scale=2.0`" in text and (out / "sweep_total.png").stat().st_size > 0
    rows = (out / "sweep.csv").read_text().splitlines()
    assert rows[0].startswith("n,scale,") and len(rows) == 5
    assert '"n=4,scale=2.0",total,12.0' in (out / "results.csv").read_text()
    # spread of the mean total over scale: mean(0.5, 3) = 1.75 vs mean(2, 12) = 7
    assert sweep.sensitivity(sweep.parse_axes(["n=2,4", "scale=0.5,2"], TinyConfig),
                             _records(out))["total"]["scale"] == pytest.approx(5.25)

    # a re-run skips the finished cells
    log.clear()
    sweep.run(tiny, [*GRID, "--out", str(out), "--quiet"])
    assert log == []
    # a sweep killed after three cells: only the fourth is run again, and inside its own
    # store only its missing units
    lines = (out / "cells.jsonl").read_text().splitlines()
    (out / "cells.jsonl").write_text("\n".join(lines[:3]) + "\n")
    units = (out / "n=4,scale=2.0" / "units.jsonl").read_text().splitlines()
    (out / "n=4,scale=2.0" / "units.jsonl").write_text("\n".join(units[:2]) + "\n")
    sweep.run(tiny, [*GRID, "--out", str(out), "--quiet"])
    assert log == [("n=4,scale=2.0", 2), ("n=4,scale=2.0", 3)]
    assert "4 of 4 cells finished" in (out / "sweep_report.md").read_text()
    # --report-only rewrites the report from the records, computing nothing
    (out / "sweep_report.md").unlink()
    log.clear()
    sweep.run(tiny, [*GRID, "--out", str(out), "--report-only"])
    assert log == [] and (out / "sweep_report.md").exists()
    with pytest.raises(sweep.SweepError, match="holds a sweep over"):
        sweep.run(tiny, ["--sweep", "n=2", "--out", str(out), "--report-only"])


def _records(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "cells.jsonl").read_text().splitlines()]


def test_a_different_sweep_or_base_config_in_the_same_out_is_refused(tmp_path):
    log: list = []
    tiny = _tiny_study(log)
    out = tmp_path / "sw"
    sweep.run(tiny, ["--sweep", "n=1,2", "--out", str(out), "--quiet"])
    with pytest.raises(StoreError, match="axes"):
        sweep.run(tiny, ["--sweep", "n=1,3", "--out", str(out), "--quiet"])
    with pytest.raises(StoreError, match="base"):
        sweep.run(tiny, ["--sweep", "n=1,2", "--seed", "1", "--out", str(out), "--quiet"])
    # a cell directory refuses another configuration on its own (the study's store)
    with pytest.raises(StoreError, match="seed"):
        Store.open(out / "n=1", "tiny", TinyConfig(n=1, seed=5).to_json())
    log.clear()
    sweep.run(tiny, ["--sweep", "n=1,3", "--out", str(out), "--quiet", "--fresh"])
    assert sorted({c for c, _ in log}) == ["n=1", "n=3"] and not (out / "n=2").exists()


@pytest.mark.parametrize("argv, message", [
    (["--sweep", "n"], "expected KEY=V1,V2"),
    (["--sweep", "=1,2"], "expected KEY=V1,V2"),
    (["--sweep"], "--sweep needs a value"),
    (["--sweep", "n=1,,2"], "empty value"),
    (["--sweep", "n="], "empty value"),
    (["--sweep", "n=1,1"], "given twice"),
    (["--sweep", "n=1", "--sweep", "n=2"], "swept twice"),
    (["--sweep", "m=1,2"], "unknown key 'm'; the keys are n, scale, seed, tags"),
    (["--sweep", "n=1.5"], "n takes integers"),
    (["--sweep", "scale=abc"], "scale takes numbers"),
    (["--sweep", "scale=inf"], "scale takes finite numbers"),
    (["--sweep", "tags=a+"], "items joined by '+'"),
    (["--sweep", "tags=a/b"], "cannot name a cell directory"),
    (["--n", "5", "--sweep", "n=1,2"], "n is also set by another flag"),
])
def test_bad_sweep_arguments_are_refused_before_anything_runs(tmp_path, argv, message):
    log: list = []
    out = tmp_path / "sw"
    with pytest.raises(sweep.SweepError, match=message.replace("+", r"\+")):
        sweep.run(_tiny_study(log), [*argv, "--out", str(out)])
    assert log == [] and not out.exists()


def test_a_cell_the_study_rejects_stops_the_sweep_before_any_cell_runs(tmp_path):
    log: list = []
    with pytest.raises(sweep.SweepError, match="cell n=0: n must be ≥ 1, got 0"):
        sweep.run(_tiny_study(log), ["--sweep", "n=2,0", "--out", str(tmp_path / "sw")])
    assert log == [] and not (tmp_path / "sw").exists()


def test_cli_errors_are_one_line_and_nothing_is_written(tmp_path, capsys):
    out = tmp_path / "sw"
    cases = [(["padgett-mc", "--sweep", "nope=1,2"], "unknown key 'nope'; the keys are runs"),
             (["padgett-mc", "--sweep", "num_landmarks=4,x"], "num_landmarks takes integers"),
             (["padgett-mc", "--landmarks", "5", "--sweep", "num_landmarks=4,6"],
              "num_landmarks is also set by another flag"),
             (["padgett-mc", "--sweep", "max_range=30,-1"], "max_range must be > 0"),
             (["padgett-mc", "--sweep", "representations=edc+foo"],
              "representations must be a non-empty subset")]
    for argv, message in cases:
        rc = cli(["study", *argv, "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and message in err, (argv, err)
        assert "Traceback" not in err
    rc = cli(["study", "padgett-mc", "--sweep", "num_landmarks=2,4", "--out", str(out)])
    assert rc == 2 and "num_landmarks must be ≥ 3" in capsys.readouterr().err
    assert not out.exists()
    # a study module without the protocol is refused naming what it lacks (every study of
    # the package is on the protocol, so a stand-in module)
    from pqrm_jax.studies import sweep as sweep_mod

    with pytest.raises(sweep_mod.SweepError, match="study demo does not support --sweep .*"
                                                   "lacks Config"):
        sweep_mod.run(types.ModuleType("demo"), ["--sweep", "x=1"])


def test_padgett_configure_applies_overrides_and_keeps_its_flags():
    from pqrm_jax.studies import padgett_mc as P

    cfg, args = P.configure(["--reduced", "--samples", "64", "--out", "x"],
                            {"max_range": 30.0, "dtheta_deg": 8.0})
    assert (cfg.runs, cfg.num_samples, cfg.max_range, cfg.dtheta_deg) == (100, 64, 30.0, 8.0)
    assert args.out == "x" and cfg.num_landmarks == P.Config().num_landmarks


# ------------------------------------------------------------------------------------------
# padgett-mc itself (slow: each cell compiles the mapper)
# ------------------------------------------------------------------------------------------

TINY = ["--runs", "3", "--levels", "2", "--samples", "8", "--quiet"]
TINY_SWEEP = [*TINY, "--sweep", "representations=edc+edc_lune+triple_cross+lr",
              "--sweep", "num_landmarks=4,5"]


def _level_files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.glob("level_*.npz"))} | {
        "levels.jsonl": (d / "levels.jsonl").read_bytes()}


@pytest.mark.slow
def test_padgett_sweep_cell_equals_the_direct_study(tmp_path):
    out = tmp_path / "sw"
    assert cli(["study", "padgett-mc", *TINY_SWEEP, "--out", str(out)]) == 0
    cell = out / "representations=edc+edc_lune+triple_cross+lr,num_landmarks=5"
    from pqrm_jax.studies import padgett_mc as P

    cfg, _ = P.configure(TINY + ["--landmarks", "5"],
                         {"representations": ("edc", "edc_lune", "triple_cross", "lr")})
    P.run_study(cfg, tmp_path / "direct", quiet=True)
    assert _level_files(cell) == _level_files(tmp_path / "direct")
    rec = {r["cell"]: r for r in _records(out)}
    s = rec[cell.name]["summary"]
    assert s["worst_normH"] in ("edc", "edc_lune", "triple_cross", "lr")
    assert set(s["claims"]) and "mean neighbour distance < 1 for σ_N < 1" in s["claims"]
    assert (out / "sweep_nd_max_below_sn1.png").exists()


_DRIVER = """
import sys
from pqrm_jax.studies import padgett_mc, sweep
sys.exit(sweep.main(padgett_mc, sys.argv[1:]))
"""


@pytest.mark.slow
def test_padgett_sweep_two_processes_equal_one(tmp_path):
    import os
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    one = tmp_path / "one"
    two = tmp_path / "two"
    base = [sys.executable, "-c", _DRIVER, *TINY_SWEEP, "--chunk", "1"]
    r = subprocess.run([*base, "--out", str(one)], env=env, cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    procs = [subprocess.Popen([*base, "--out", str(two), "--coordinator", f"127.0.0.1:{port}",
                               "--processes", "2", "--process-id", str(i)], env=env, cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-2000:]
    for cell in sorted(x.name for x in one.iterdir() if x.is_dir()):
        assert _level_files(one / cell) == _level_files(two / cell), cell
    assert (one / "cells.jsonl").read_bytes() == (two / "cells.jsonl").read_bytes()
