"""Chunk sizes from the device memory (``pqrm_jax/studies/chunking.py``, docs/studies.md
§chunks): qlink's pool lanes sized per world, stored and reused, and changing no trial.

qbsp's and hssh-plus's sized chunks are tested in their study tests (``test_bsp_study.py``,
``test_hssh_study.py``), padgett-mc's in ``test_pqrm_study.py``."""

from __future__ import annotations

import json

import pytest

from pqrm_jax.studies import chunking, qlink
from pqrm_jax.studies.store import StudyError


def test_fit_is_pick_chunk_then_cpu_cap_then_balance():
    """The shared tail of the studies' ``auto_chunk``: None without memory figures (the
    study's fallback), the CPU cap only on a CPU backend, the calls evened out on request,
    a device too small for one lane refused naming the option."""
    import jax

    mib = 1 << 20
    assert chunking.fit(mib, 100 * mib, total=300, option="--chunk") == 32
    assert chunking.fit(mib, 100 * mib, total=300, option="--chunk", even=True) == 30
    cpu = jax.local_devices()[0].platform == "cpu"
    assert chunking.fit(mib, 100 * mib, total=300, option="--chunk", cpu_cap=8) == \
        (8 if cpu else 32)
    assert chunking.fit(mib, 100 * mib, total=20, devices=4, option="--chunk") == 20
    assert chunking.fit(None, 100 * mib, total=300, option="--chunk") is None
    assert chunking.fit(0, 100 * mib, total=300, option="--chunk") is None
    assert chunking.fit(mib, None, total=300, option="--chunk") is None
    assert chunking.budget(1000) == 1000
    with pytest.raises(StudyError, match="--chunk-cells cannot go below one lane"):
        chunking.fit(1 << 30, 100 * mib, total=4, option="--chunk-cells")


@pytest.mark.slow
def test_qlink_pool_sized_from_memory_stored_and_changing_no_trial(tmp_path, capsys):
    args = ["--reduced", "--max-pairs", "16", "--no-progress"]
    auto, four = tmp_path / "auto", tmp_path / "four"
    assert qlink.main([*args, "--out", str(auto), "--chunk", "0"]) == 0
    assert "world 0: --chunk 16 pool lanes per call, sized from the memory" in \
        capsys.readouterr().out
    assert json.loads((auto / "world_00.json").read_text())["chunk"] == 16  # capped: 16 pairs
    assert qlink.main([*args, "--out", str(four), "--chunk", "4"]) == 0
    assert json.loads((four / "world_00.json").read_text())["chunk"] == 4
    names = sorted(p.name for p in (auto / "trials").glob("*.csv"))
    assert names and names == sorted(p.name for p in (four / "trials").glob("*.csv"))
    for n in names:  # another pool width: the same trials, bit for bit
        assert (auto / "trials" / n).read_text() == (four / "trials" / n).read_text(), n
    assert (auto / "trials.csv").read_text() == (four / "trials.csv").read_text()
    # a missing trials file is recomputed with the world's stored chunk: a 64 KiB device
    # could not size one, so no probe runs
    gone = auto / "trials" / names[0]
    before = gone.read_text()
    gone.unlink()
    assert qlink.main([*args, "--out", str(auto), "--chunk", "0",
                       "--memory-bytes", "65536"]) == 0
    assert gone.read_text() == before
    # a fresh world on that device is refused naming the option
    with pytest.raises(StudyError, match="--chunk cannot go below one lane"):
        qlink.main([*args, "--out", str(tmp_path / "small"), "--chunk", "0",
                    "--memory-bytes", "65536"])


def test_auto_is_the_one_sizer_whole_then_probe_then_fallback():
    """``chunking.auto`` (the sizer padgett-mc and qbsp call): the whole program when it fits
    in FRACTION of the budget (the probe is then never compiled), else the probe's bytes per
    lane through ``fit``, else the fallback without memory figures; a device too small for
    one lane is refused naming the option."""
    mib = 1 << 20
    calls = []

    def probe():
        calls.append(1)
        return 2 * mib  # a probe of 2 lanes per device: 1 MiB per lane

    kw = dict(total=1000, option="--chunk", per_probe=2, memory_bytes=100 * mib)
    assert chunking.auto(probe, whole=lambda n: 50 * mib, **kw) == 1000 and not calls
    assert chunking.auto(probe, whole=lambda n: 50 * mib + 1, **kw) == 32 and calls
    assert chunking.auto(probe, whole=lambda n: None, **kw) == 32
    assert chunking.auto(probe, **kw, devices=4) == 4 * 32
    assert chunking.auto(probe, **dict(kw, total=10), devices=4, whole=lambda n: 1) == 12
    assert chunking.auto(probe, **kw, even=True) == 32  # 1000 / 32: 32 calls of 32 (31.25)
    assert chunking.auto(probe, **dict(kw, total=40), even=True) == 20  # 2 calls of 20
    assert chunking.auto(lambda: None, **kw) == chunking.FALLBACK_CHUNK
    assert chunking.auto(lambda: 0, **kw, fallback=7) == 7
    with pytest.raises(StudyError, match="--chunk cannot go below one lane"):
        chunking.auto(lambda: 1 << 30, total=4, option="--chunk", memory_bytes=100 * mib)


def test_auto_caps_the_first_program_and_the_fallback_on_a_cpu():
    """``cpu_cap`` bounds the first program ``auto`` tries on a CPU backend, evened out over
    the lanes (1 000 lanes: 100; 150: two calls of 75), and the fallback without memory
    figures; on another backend it changes neither."""
    import jax

    mib = 1 << 20
    cpu = jax.local_devices()[0].platform == "cpu"
    asked = []

    def whole(lanes):
        asked.append(lanes)
        return 1

    kw = dict(option="--chunk", memory_bytes=100 * mib, whole=whole, cpu_cap=100)
    assert chunking.auto(lambda: None, total=1000, **kw) == (100 if cpu else 1000)
    assert chunking.auto(lambda: None, total=150, **kw) == (75 if cpu else 150)
    assert asked == ([100, 75] if cpu else [1000, 150])
    assert chunking.auto(lambda: None, total=1000, option="--chunk", cpu_cap=100) == \
        (100 if cpu else chunking.FALLBACK_CHUNK)


def test_program_bytes_is_remembered_per_program(monkeypatch):
    """XLA's memory analysis of a large program takes tens of ms; each padgett-mc level checks
    its chunk's program again, so the figure is computed once per compiled program."""
    import jax
    import jax.numpy as jnp

    from pqrm_jax.studies import chunking

    c = jax.jit(lambda x: x + 1).lower(jnp.ones(4)).compile()
    d = jax.jit(lambda x: x * 2).lower(jnp.ones(8)).compile()
    calls = []
    orig = type(c).memory_analysis
    monkeypatch.setattr(type(c), "memory_analysis",
                        lambda self: calls.append(self) or orig(self))
    first = [chunking.program_bytes(c), chunking.program_bytes(d)]
    again = [chunking.program_bytes(c), chunking.program_bytes(d)]
    assert first == again and all(b is not None and b > 0 for b in first)
    assert first[0] != first[1] and len(calls) == 2
