"""Chunk sizes from the device's memory: how many lanes (runs) one compiled call may take.

A study that maps many independent runs in one compiled call (padgett-mc's chunks of runs)
sizes the call from what the device can hold instead of a constant tuned for one machine:

1. :func:`available_bytes` — the memory one device may use now: ``bytes_limit -
   bytes_in_use`` of ``device.memory_stats()`` where the backend reports it (GPU, TPU), else
   the host's available RAM (``MemAvailable`` of ``/proc/meminfo``, else ``os.sysconf``)
   shared by this process's local devices;
2. :func:`program_bytes` — what XLA's buffer assignment says a compiled program needs per
   device (arguments + outputs + temporaries, ``Compiled.memory_analysis()``);
3. :func:`pick_chunk` — from a per-lane bound (a one-lane probe program's bytes: its fixed
   part is then counted once per lane, so ``n`` lanes need at most ``n`` times it) the largest
   power-of-two number of lanes per device whose bytes stay under ``FRACTION`` of the
   budget, capped at the work there is. Powers of two keep the choice stable when the free
   memory moves a little, so two runs of one study on one machine pick the same chunk
   (the chunk changes float bits, so a study stores it and reuses it on resume);
4. :func:`check_fits` — a chosen (or user-given) chunk whose program needs more than the
   budget fails with a :class:`~pqrm_jax.studies.store.StudyError` naming the chunk option,
   before anything runs;
5. :func:`resolve` — the chunk one run of a study uses, the same on every process: the
   user's, else the one stored in ``out/config.json`` (a resume keeps its layout whatever the
   free memory is now), else a new one sized by the study (``size()``, on process 0 only).

:func:`auto` is the one chunk sizer every study calls (steps 1–3 with the study's probe
program, the CPU cap, the evening-out and the :data:`FALLBACK_CHUNK` when the machine gives
no memory figures); the split of the chunks over processes is
:func:`~pqrm_jax.studies.distributed.map_chunks`.

Studies using it (docs/studies.md): padgett-mc (``--chunk``: runs per call), qbsp
(``--chunk``: environments per call, four lanes each), qlink (``--chunk``: pool lanes of the
navigation executive) and hssh-plus (cells per cellular call).

The budget can be passed explicitly (``memory_bytes``) for tests and for users who share a
device; nothing here mocks JAX.

>>> pick_chunk(per_lane_bytes=1 << 20, budget_bytes=100 << 20, total=1000, devices=1)
32
>>> pick_chunk(1 << 20, 100 << 20, total=20, devices=4)  # capped at the work: 5 lanes each
20
>>> check_fits(3 << 30, 1 << 30, option="--chunk-runs", what="a chunk of 64 runs")
Traceback (most recent call last):
...
pqrm_jax.studies.store.StudyError: a chunk of 64 runs needs about 3072 MiB per device but \
FRACTION = 0.5 of the 1024 MiB available is 512 MiB; lower --chunk-runs
"""

from __future__ import annotations

import contextlib
import json
import os
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["FALLBACK_CHUNK", "FRACTION", "auto", "available_bytes", "budget", "check_fits",
           "fit", "pick_chunk", "program_bytes", "balance", "resolve", "stored_chunk"]

#: share of a device's available memory one chunk may use: XLA's own runtime buffers, the
#: host-side copies of the results and other processes on the machine need the rest
FRACTION = 0.5

#: lanes per call when neither the device nor the OS reports its memory (:func:`auto`)
FALLBACK_CHUNK = 250


def _host_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return None


def available_bytes(device: Any = None) -> int | None:
    """Bytes one device may still allocate (None when neither the device nor the OS says).

    A device that reports ``memory_stats()`` (GPU, TPU) gives ``bytes_limit - bytes_in_use``;
    the CPU backend reports none, so the host's available RAM is shared by the local devices
    (several forced host devices live in the same RAM).
    """
    import jax

    device = device or jax.local_devices()[0]
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001  (backends without the call raise various errors)
        stats = None
    if stats and stats.get("bytes_limit"):
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    host = _host_available()
    if host is None:
        return None
    same = [d for d in jax.local_devices() if d.platform == device.platform]
    return host // max(len(same), 1)


def budget(memory_bytes: int | None = None) -> int | None:
    """``memory_bytes`` when given (tests, users sharing a device), else
    :func:`available_bytes` of the first local device.

    >>> budget(1 << 20)
    1048576
    """
    return available_bytes() if memory_bytes is None else memory_bytes


def program_bytes(compiled: Any) -> int | None:
    """Arguments + outputs + temporaries of a compiled program, per device (XLA's analysis).

    None when the backend gives no analysis. Remembered per program: XLA's analysis of the
    padgett-mc runner takes ≈ 30 ms, and every noise level checks its chunk again.
    """
    try:
        return _PROGRAM_BYTES[compiled]
    except (KeyError, TypeError):  # TypeError: not weakly referable, not remembered
        pass
    try:
        m = compiled.memory_analysis()
    except Exception:  # noqa: BLE001  (not implemented on every backend)
        return None
    if m is None:
        return None
    out = int(m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
              - m.alias_size_in_bytes)
    with contextlib.suppress(TypeError):
        _PROGRAM_BYTES[compiled] = out
    return out


_PROGRAM_BYTES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def pick_chunk(per_lane_bytes: float, budget_bytes: int, *, total: int, devices: int,
               fraction: float = FRACTION, option: str = "--chunk-runs") -> int:
    """Lanes per call: ``devices`` × the largest power of two of lanes per device that fits.

    Args:
        per_lane_bytes: estimated bytes of one lane on one device.
        budget_bytes: bytes one device may use (:func:`available_bytes`).
        total: the lanes there are (the chunk is capped at ``total`` rounded up to a
            multiple of ``devices``).
        devices: devices one call is sharded over.
        fraction: share of the budget one call may use.
        option: the command-line option that sets the chunk by hand (named in errors).

    Raises:
        StudyError: not even one lane per device fits.
    """
    if per_lane_bytes <= 0 or budget_bytes is None:
        raise ValueError(f"need a positive per-lane estimate and a budget, got "
                         f"{per_lane_bytes} and {budget_bytes}")
    per_device = int(fraction * budget_bytes // per_lane_bytes)
    if per_device < 1:
        from .store import StudyError

        raise StudyError(f"one lane needs about {_size(per_lane_bytes)} per device but "
                         f"FRACTION = {fraction:g} of the {_size(budget_bytes)} "
                         f"available is {_size(fraction * budget_bytes)}; the device "
                         f"is too small for this configuration ({option} cannot go below "
                         f"one lane per device)")
    need = -(-total // devices)
    lanes = 1 << (per_device.bit_length() - 1)  # largest power of two <= per_device
    return devices * min(lanes, need)


def fit(per_lane_bytes: float | None, budget_bytes: int | None, *, total: int,
        devices: int = 1, option: str, cpu_cap: int | None = None,
        even: bool = False) -> int | None:
    """The chunk a study's probe allows: :func:`pick_chunk`, at most ``cpu_cap`` on the CPU
    backend (where the caches, not the memory, bound it), then :func:`balance` (if ``even``).

    Args:
        per_lane_bytes: one lane's bytes on one device from the study's probe program
            (None or 0 when the backend gives no memory analysis).
        budget_bytes: :func:`budget` (None when neither the device nor the OS says).
        total, devices, option: as for :func:`pick_chunk`.
        cpu_cap: the most lanes per call on a CPU backend (None: no cap).
        even: even the calls out over ``total`` (:func:`balance`).

    Returns:
        The chunk, or None without memory figures (the caller's fallback applies).

    Raises:
        StudyError: not even one lane per device fits (:func:`pick_chunk`).

    >>> fit(1 << 20, 100 << 20, total=300, option="--chunk", even=True)  # 32 -> 10 calls of 30
    30
    >>> fit(None, 100 << 20, total=300, option="--chunk") is None
    True
    """
    if not per_lane_bytes or budget_bytes is None:
        return None
    chunk = pick_chunk(per_lane_bytes, budget_bytes, total=total, devices=devices,
                       option=option)
    if cpu_cap is not None and _on_cpu():
        chunk = min(chunk, cpu_cap)
    return balance(chunk, total, devices) if even else chunk


def _on_cpu() -> bool:
    import jax

    return jax.local_devices()[0].platform == "cpu"


def auto(probe: Callable[[], int | None], *, total: int, option: str, devices: int = 1,
         per_probe: float = 1, memory_bytes: int | None = None, cpu_cap: int | None = None,
         even: bool = False, fallback: int = FALLBACK_CHUNK,
         whole: Callable[[int], int | None] | None = None, say: str | None = None,
         unit: str = "lanes") -> int:
    """The chunk (lanes per compiled call) sized from the device memory: the one chunk sizer.

    1. ``whole(lanes)`` (optional): the bytes of the program of the first choice of lanes
       per call — all ``total`` lanes (rounded up to ``devices``), on a CPU backend at most
       ``cpu_cap`` evened out over ``total`` (:func:`balance`) — the program the study then
       runs, so in the usual case nothing else is compiled; taken when it needs at most
       :data:`FRACTION` of the budget;
    2. else ``probe()``: the bytes of a probe program of ``per_probe`` lanes per device (its
       fixed part then counted for every lane: ``n`` lanes need at most ``n / per_probe``
       times it); :func:`fit` takes the largest power of two per device that fits (at most
       ``cpu_cap`` on a CPU backend, evened out over ``total`` if ``even``);
    3. without memory figures (the backend gives no analysis, or neither the device nor the
       OS reports its memory): ``fallback`` (at most ``cpu_cap`` on a CPU backend).

    Args:
        probe: bytes of the probe program on one device (None: no analysis), called at most
            once (not when ``whole`` fits).
        total: the lanes there are.
        option: the command-line option that sets the chunk by hand (named in errors).
        devices: devices one call is sharded over.
        per_probe: lanes per device of the probe program.
        memory_bytes: the budget per device (None: what the device reports, :func:`budget`).
        cpu_cap, even: as for :func:`fit`.
        fallback: the chunk without memory figures.
        whole: lanes ↦ bytes of the program of that many lanes in one call, called with
            the first choice above (None: not tried).
        say: a prefix (the study's name) to print the sized chunk with; None prints nothing.
        unit: what one lane is, for that line (``"environments"``).

    Returns:
        Lanes per call, a multiple of ``devices``.

    Raises:
        StudyError: not even one lane per device fits (names ``option``).

    >>> auto(lambda: 1 << 20, total=1000, option="--chunk", memory_bytes=100 << 20)
    32
    >>> auto(lambda: 1 << 20, total=1000, option="--chunk", memory_bytes=100 << 20,
    ...      whole=lambda n: 40 << 20)  # all 1000 in one call fit in half of 100 MiB
    1000
    >>> auto(lambda: None, total=1000, option="--chunk", fallback=128)
    128
    >>> auto(lambda: 3 << 20, total=1000, option="--chunk", memory_bytes=100 << 20,
    ...      per_probe=3, say="demo", unit="runs")
    demo: --chunk 32 runs per call, sized from the memory (1.0 MiB per run and device, \
100 MiB available)
    32
    """
    budget_bytes = budget(memory_bytes)
    first = -(-total // devices) * devices
    if cpu_cap is not None and _on_cpu():  # the caches, not the memory, bound a CPU's chunk
        first = balance(min(first, cpu_cap), total, devices)
        fallback = min(fallback, cpu_cap)
    if whole is not None and budget_bytes is not None:
        nbytes = whole(first)
        if nbytes is not None and nbytes <= FRACTION * budget_bytes:
            return first
    nbytes = probe()
    per_lane = nbytes / per_probe if nbytes else None
    chunk = fit(per_lane, budget_bytes, total=total, devices=devices, option=option,
                cpu_cap=cpu_cap, even=even)
    if chunk is None:
        return fallback
    if say is not None:
        one = unit[:-1] if unit.endswith("s") else unit
        print(f"{say}: {option} {chunk} {unit} per call, sized from the memory "
              f"({per_lane / 2**20:.1f} MiB per {one} and device, "
              f"{budget_bytes / 2**20:.0f} MiB available)")
    return chunk


def check_fits(nbytes: int | None, budget_bytes: int | None, *, option: str, what: str,
               fraction: float = FRACTION) -> None:
    """Refuse a program needing more than ``fraction`` of the budget (message names option).

    Nothing is checked when either number is unknown (None).
    """
    if nbytes is None or budget_bytes is None or nbytes <= fraction * budget_bytes:
        return
    from .store import StudyError

    raise StudyError(f"{what} needs about {_size(nbytes)} per device but FRACTION = "
                     f"{fraction:g} of the {_size(budget_bytes)} available is "
                     f"{_size(fraction * budget_bytes)}; lower {option}")


def _size(nbytes: float) -> str:
    for unit, k in (("MiB", 1 << 20), ("KiB", 1 << 10)):
        if nbytes >= k:
            return f"{nbytes / k:.0f} {unit}"
    return f"{nbytes:.0f} B"


def balance(chunk: int, total: int, devices: int = 1) -> int:
    """The smallest multiple of ``devices`` that covers ``total`` in as many calls as
    ``chunk`` does: the same number of compiled calls with less padding in the last one.

    >>> balance(256, 300)  # two calls either way; the second no longer 212 lanes of padding
    150
    >>> balance(8, 20, devices=4)
    8
    """
    calls = -(-total // max(chunk, 1))
    per_call = -(-total // calls)
    return max(devices, -(-per_call // devices) * devices)


def stored_chunk(out: Path, key: str = "chunk") -> int | None:
    """``layout[key]`` of ``out/config.json`` (None when there is no valid one).

    >>> stored_chunk(Path("/nonexistent")) is None
    True
    """
    try:
        chunk = json.loads((Path(out) / "config.json").read_text())["layout"][key]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return chunk if isinstance(chunk, int) and not isinstance(chunk, bool) and chunk >= 1 \
        else None


def resolve(given: int | None, out: Path, size: Callable[[], int], *, fresh: bool = False,
            cluster: Any = None, key: str = "chunk") -> int:
    """The chunk of this run, the same on every process of ``cluster``.

    ``given`` (the user's option) wins; else process 0 reuses the chunk stored in
    ``out/config.json`` (unless ``fresh``) or calls ``size()`` (the study's memory-based
    choice), and broadcasts it (:func:`~pqrm_jax.studies.distributed.decide`: a failure of
    ``size`` on process 0 is raised on every process).

    >>> resolve(None, Path("/nonexistent"), lambda: 16)
    16
    >>> resolve(8, Path("/nonexistent"), lambda: 16)
    8
    """
    if given is not None:
        return int(given)
    from . import distributed

    cluster = cluster or distributed.current()

    def choose() -> list[int]:
        stored = None if fresh else stored_chunk(out, key)
        return [stored or int(size())]

    return int(distributed.decide(cluster, 1, choose)[0])
