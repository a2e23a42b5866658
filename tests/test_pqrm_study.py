"""padgett-mc study: CLI end to end, resume after interruption, sharding over 1 vs 4 devices."""

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pqrm_jax.studies import padgett_mc
from pqrm_jax.studies.store import StoreError

TINY = ["--runs", "4", "--levels", "2", "--samples", "16", "--landmarks", "4", "--quiet"]


def _levels(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "levels.jsonl").read_text().splitlines() if x]


def test_cli_study_report_and_resume(tmp_path):
    out = tmp_path / "mc"
    assert padgett_mc.main([*TINY, "--out", str(out)]) == 0
    full = _levels(out)
    n_levels = len(padgett_mc.Config(levels=2).sigma_levels())
    assert [d["level"] for d in full] == list(range(n_levels))
    report = (out / "report.md").read_text()
    assert "| claim | published | measured | interval | verdict |" in report
    assert "worst-case EDC mean entropy" in report and "lune" in report
    for fig in ("fig2_6_neighbor_distance.png", "fig2_7_entropy.png", "fig2_16_topn.png",
                "fig2_8_error_locations.png", "fig2_10_entropy_representations.png"):
        assert (out / fig).stat().st_size > 1000
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["num_landmarks"] == 4 and cfg["num_samples"] == 16 and "notes" in cfg
    zero = full[0]["reps"]["edc"]
    assert zero["entropy_mean"] == 0.0 and zero["error_mean"] == 0.0  # σ_R = 0: exact map
    # the claims of a run without the ranked representations, or whose metrics do not vary
    # over the levels, are "not checked" (they crashed the report of such a sweep cell)
    from pqrm_jax.studies import _padgett_report as R

    cfg_, lines_, arrays_ = R.load_results(out)
    some = {**cfg_, "representations": ["edc"]}
    for ln in lines_:
        ln["reps"] = {"edc": {**ln["reps"]["edc"], "error_mean": 0.5, "p_ml_mean": 0.5}}
    rows = {r[0]: r[-1] for r in R.claim_rows(some, lines_, arrays_)}
    assert rows["normalised entropy: best EDC-lune-merged, worst LR"].startswith("not checked")
    assert rows["P(ML state) falls as the error rate rises (Fig. 2.11b)"].startswith(
        "not checked")
    # interrupt: lose the last two levels and tear the last line, then resume
    lines = (out / "levels.jsonl").read_text().splitlines()
    (out / "levels.jsonl").write_text("\n".join(lines[:-2]) + "\n" + lines[-2][:20])
    (out / f"level_{n_levels - 1:02d}.npz").unlink()
    assert padgett_mc.main([*TINY, "--out", str(out)]) == 0
    assert _levels(out) == full
    # a different config in the same directory is refused
    with pytest.raises(StoreError, match="different config"):
        padgett_mc.main([*TINY[:-1], "--samples", "32", "--quiet", "--out", str(out)])


_SHARD_SCRIPT = """
import json, sys, jax, numpy as np
from pqrm_jax.studies import padgett_mc as P
cfg = P.Config(runs=8, levels=1, num_samples=16, num_landmarks=4, chunk_runs=8,
               representations=("edc", "lr"))
res = P.run_level(cfg, 0, 40.0)
flat = {"devices": len(jax.devices())}
for rep in ("edc", "lr"):
    for k in ("entropy", "error", "p_ml", "topn", "confusion"):
        flat[f"{rep}/{k}"] = np.asarray(res[rep][k]).tolist()
flat["mapped"] = np.asarray(res["n_mapped"]).tolist()
print(json.dumps(flat))
"""


def _run_devices(n: int) -> dict:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}",
               JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", _SHARD_SCRIPT], capture_output=True, text=True,
                          env=env, check=True, cwd=Path(__file__).parent.parent)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_sharded_runs_identical_on_1_and_4_devices():
    one, four = _run_devices(1), _run_devices(4)
    assert one.pop("devices") == 1 and four.pop("devices") == 4
    assert one.keys() == four.keys()
    for k in one:
        np.testing.assert_array_equal(np.asarray(one[k]), np.asarray(four[k]), err_msg=k)
    assert np.asarray(one["edc/entropy"]).std() > 0  # the runs differ from each other


def _assert_same_leaves(want, got, label: str = "") -> None:
    """Every leaf of the result pytrees ``want`` and ``got`` equal, bit for bit."""
    import jax

    flat_w = jax.tree_util.tree_leaves_with_path(want)
    flat_g = jax.tree_util.tree_leaves(got)
    assert len(flat_w) == len(flat_g)
    for (path, a), b in zip(flat_w, flat_g, strict=True):
        np.testing.assert_array_equal(a, b, err_msg=f"{label}{jax.tree_util.keystr(path)}")


def _dense_equals_sparse(cfg, sigmas):
    for sigma in sigmas:
        dense = padgett_mc.run_level(cfg, 0, sigma, dense=True)
        sparse = padgett_mc.run_level(cfg, 0, sigma)
        _assert_same_leaves(dense, sparse, f"σ_R={sigma} ")
        assert np.asarray(sparse["n_updates"]).sum() > 0
        assert sigma == 0 or np.asarray(sparse["double_cross"]["entropy"]).std() > 0


def test_sparse_batched_runner_equals_dense_per_run_runner():
    """The study's runner samples only the seen triplets; every result leaf equals the dense
    reference bit for bit — at the study's map (10 landmarks, 256 samples, the six
    representations, 23 poses; 12 runs here, the slow test below has 1000). Before issue 31
    the eq. 2.10 normaliser was contracted into FMAs differently by the two programs (entropy
    and P(ML) of double_cross and triple_cross differed by up to 2.4e-7)."""
    cfg = padgett_mc.Config(runs=12, levels=1, chunk_runs=12)
    _dense_equals_sparse(cfg, (0.0, 50.0))
    small = padgett_mc.Config(runs=6, levels=1, num_samples=32, num_landmarks=6, chunk_runs=6,
                              representations=("edc", "double_cross", "lr"))
    _dense_equals_sparse(small, (30.0,))


def test_chunk_vector_width_moves_no_result(monkeypatch):
    """Issue 31: the chunk program is compiled with the kernel's 512-bit vectors (3 % less
    CPU for the full study on an AVX-512 host); every result leaf equals that of the program
    compiled without them, at the study's map."""
    from pqrm_jax.pqrm.measurement import KERNEL_COMPILER_OPTIONS

    cfg = padgett_mc.Config(runs=12, levels=1, chunk_runs=12)
    assert KERNEL_COMPILER_OPTIONS  # there is something to pass
    assert KERNEL_COMPILER_OPTIONS.items() <= padgett_mc.CHUNK_COMPILER_OPTIONS.items()
    monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS", dict(KERNEL_COMPILER_OPTIONS))
    monkeypatch.setattr(padgett_mc, "_AOT", {})
    with_opts = padgett_mc.run_level(cfg, 0, 50.0)
    monkeypatch.setattr(padgett_mc, "_AOT", {})  # compile again
    # the options reach XLA: an option it does not know is refused, by name
    monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS", {"xla_no_such_option": 1})
    with pytest.raises(Exception, match="xla_no_such_option"):
        padgett_mc.run_level(cfg, 0, 50.0)
    monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS", {})  # without the options
    plain = padgett_mc.run_level(cfg, 0, 50.0)
    _assert_same_leaves(plain, with_opts)
    assert np.asarray(plain["edc"]["entropy"]).std() > 0


#: the result leaves whose float sums may move in the last bits with the program's compiler
#: options (numerics version 4) or its chunk (docs/studies.md §padgett-mc: the layout)
FLOAT_METRIC_LEAVES = ("entropy", "p_ml", "xy", "dab")


def _assert_same_but_float_metrics(want, got) -> None:
    """Every leaf equal bit for bit except :data:`FLOAT_METRIC_LEAVES`, which agree within a
    few ulps (and are not all equal to zero: the comparison has something to compare)."""
    import jax

    flat_w = jax.tree_util.tree_leaves_with_path(want)
    for (path, a), b in zip(flat_w, jax.tree_util.tree_leaves(got), strict=True):
        name = jax.tree_util.keystr(path)
        if path[-1].key in FLOAT_METRIC_LEAVES:
            np.testing.assert_allclose(b, a, rtol=4e-6, atol=1e-6, err_msg=name)
            assert np.any(np.asarray(a) != 0), name
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)


def test_no_ynn_fusions_keep_the_maps_and_move_only_float_metrics(monkeypatch):
    """Issue 31, numerics version 4: the chunk program is compiled without YNNPACK fusions
    (a 1 000-run level 15 % less CPU). The maps are the same bit for bit, so is every
    discrete result (counts, error, top-n and neighbour rates, confusion, the error
    locations' states); only the float sums of the metrics (entropy, P(ML), the error
    locations' normalised positions) may move, by a few ulps."""
    import jax
    import jax.numpy as jnp

    from pqrm_jax.pqrm.measurement import KERNEL_COMPILER_OPTIONS

    opts = padgett_mc.chunk_compiler_options()
    if not padgett_mc.NO_YNN_FUSIONS.items() <= opts.items():
        pytest.skip("this jaxlib's XLA has no YNNPACK fusions to turn off")
    assert opts == padgett_mc.CHUNK_COMPILER_OPTIONS
    assert padgett_mc.Config().to_json()["numerics"] == 4
    # the maps: the study's mapping (the loop of Mapper.update_batch), compiled both ways
    cfg = padgett_mc.Config(runs=24, levels=1, chunk_runs=24)
    maps, _ = padgett_mc._make_maps_fn(cfg)
    keys = padgett_mc.run_keys(cfg, 0, np.arange(cfg.runs))
    lowered = jax.jit(lambda k, s: maps(k, s)[1]).lower(keys, jnp.float32(20.0))
    got = [jax.device_get(lowered.compile(compiler_options=o)(keys, jnp.float32(20.0)))
           for o in (KERNEL_COMPILER_OPTIONS, opts)]
    _assert_same_leaves(*got, "map ")
    assert np.asarray(got[0].mapped).sum() > 0
    # the metrics: every leaf equal except the float sums, and those within a few ulps
    results = []
    for o in (KERNEL_COMPILER_OPTIONS, opts):
        monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS", dict(o))
        monkeypatch.setattr(padgett_mc, "_AOT", {})
        results.append(padgett_mc.run_level(cfg, 0, 20.0))
    _assert_same_but_float_metrics(*results)


def test_chunk_compiler_options_without_an_option_xla_does_not_know(monkeypatch):
    """A jaxlib whose XLA has no YNNPACK fusion option compiles the chunk program without
    it (nothing to turn off); every other option still reaches XLA unchanged."""
    from pqrm_jax.pqrm.measurement import KERNEL_COMPILER_OPTIONS

    unknown = {"xla_cpu_no_such_ynn_option": ""}
    monkeypatch.setattr(padgett_mc, "NO_YNN_FUSIONS", unknown)
    monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS",
                        dict(KERNEL_COMPILER_OPTIONS, **unknown))
    assert padgett_mc.chunk_compiler_options() == KERNEL_COMPILER_OPTIONS
    monkeypatch.setattr(padgett_mc, "CHUNK_COMPILER_OPTIONS", {"xla_no_such_option": 1})
    assert padgett_mc.chunk_compiler_options() == {"xla_no_such_option": 1}


def test_auto_chunk_on_cpu_caps_the_chunk_and_evens_it_out(monkeypatch):
    """On a CPU the automatic chunk is at most ``CPU_CHUNK_RUNS`` runs, evened out over the
    runs (9 runs, cap 4: three calls of 3); the results equal those of one call of every
    run, bit for bit except the float sums of the metrics (the chunk is part of the stored
    layout for that reason)."""
    import jax

    if jax.local_devices()[0].platform != "cpu":
        pytest.skip("the cap applies on a CPU backend")
    cfg = padgett_mc.Config(runs=9, levels=1, num_samples=16, num_landmarks=5,
                            representations=("edc", "lr"))
    monkeypatch.setattr(padgett_mc, "CPU_CHUNK_RUNS", 4)
    assert padgett_mc.auto_chunk(cfg, memory_bytes=10**12) == 3
    monkeypatch.setattr(padgett_mc, "CPU_CHUNK_RUNS", 100)
    assert padgett_mc.auto_chunk(cfg, memory_bytes=10**12) == 9  # fewer runs than the cap
    chunked = padgett_mc.run_level(dataclasses.replace(cfg, chunk_runs=3), 0, 30.0)
    whole = padgett_mc.run_level(dataclasses.replace(cfg, chunk_runs=9), 0, 30.0)
    _assert_same_but_float_metrics(whole, chunked)


@pytest.mark.slow
def test_sparse_equals_dense_at_the_study_size():
    """Issue 31: the full level of 1000 runs, at a low and a high noise level."""
    cfg = padgett_mc.Config(runs=1000, levels=1, chunk_runs=1000)
    _dense_equals_sparse(cfg, (5.0, 50.0))


def test_chunk_sized_from_memory_reused_on_resume_and_refused_when_too_large(tmp_path):
    """chunk_runs=None sizes the chunk from the device memory (here a fake figure passed as
    ``memory_bytes``); a resume keeps the stored chunk; a chunk, given or chosen, that does
    not fit is refused with a message naming --chunk before it runs."""
    import dataclasses

    from pqrm_jax.studies import chunking
    from pqrm_jax.studies.store import StudyError

    cfg = padgett_mc.Config(runs=4, levels=1, num_samples=8, num_landmarks=4,
                            representations=("edc",))
    assert cfg.chunk_runs is None
    probe, _ = padgett_mc.chunk_program(dataclasses.replace(cfg, chunk_runs=1), 1)
    one = chunking.program_bytes(probe)  # bounds one run's bytes (1 device here)
    assert one and one > 0
    assert padgett_mc.auto_chunk(cfg, memory_bytes=10**12) == 4  # capped at the runs
    # room for 2.5 runs in FRACTION of the memory: the largest power of two that fits, 2
    small = int(2.5 * one / chunking.FRACTION)
    assert padgett_mc.auto_chunk(cfg, memory_bytes=small) == 2
    out = tmp_path / "mc"
    padgett_mc.run_study(cfg, out, quiet=True, memory_bytes=small)
    assert json.loads((out / "config.json").read_text())["layout"]["chunk"] == 2
    # resumed with more memory: the stored chunk (hence the float bits) is kept, not refused
    (out / "level_01.npz").unlink()
    padgett_mc.run_study(cfg, out, quiet=True, memory_bytes=10**12)
    assert json.loads((out / "config.json").read_text())["layout"]["chunk"] == 2
    assert (out / "level_01.npz").exists()
    # a given chunk too large for the memory (the chunk of 2 compiled above: no new
    # program), and a memory too small for one run
    two = dataclasses.replace(cfg, chunk_runs=2)
    need = chunking.program_bytes(padgett_mc.chunk_program(two, 2)[0])
    with pytest.raises(StudyError, match=r"a chunk of 2 runs .* lower --chunk\b"):
        padgett_mc.run_study(two, tmp_path / "big", quiet=True,
                             memory_bytes=int(0.9 * need / chunking.FRACTION))
    assert not (tmp_path / "big" / "levels.jsonl").exists()
    with pytest.raises(StudyError, match=r"--chunk\b"):
        padgett_mc.run_study(cfg, tmp_path / "tiny", quiet=True, memory_bytes=1000)


def test_levels_side_by_side_compile_each_program_under_the_lock(tmp_path, monkeypatch):
    """Two noise levels run in two threads (``level_workers``); JAX does not serialise two
    threads dispatching the same new eager op, so each may compile it (measured: two threads
    calling ``jnp.ones`` at once wrote 3 persistent-cache entries for 2 programs in 2 of 8
    processes; CI's second padgett-mc process then found 11 programs where the first had
    written 12). Every program a level thread compiles is therefore compiled holding
    ``padgett_mc._LOCK``: the compile events of the worker threads are checked here with the
    in-memory caches cleared, so the eager key derivation compiles anew."""
    import jax
    from compile_count import compiles_by_thread

    monkeypatch.setattr(padgett_mc, "level_workers", lambda cluster=None: 2)
    cfg = padgett_mc.Config(runs=3, levels=2, num_samples=8, num_landmarks=4, chunk_runs=2,
                            representations=("edc",))
    padgett_mc.run_study(cfg, tmp_path / "warm", quiet=True)  # the runner's program, compiled
    jax.clear_caches()
    with compiles_by_thread(padgett_mc._LOCK.locked) as compiled:
        padgett_mc.run_study(dataclasses.replace(cfg, seed=1), tmp_path / "run", quiet=True)
    worker = [locked for _, main, locked in compiled if not main]
    assert worker, "the level threads compiled nothing after clear_caches: the check is empty"
    assert all(worker), f"{worker.count(False)} of {len(worker)} compiles outside the lock"
