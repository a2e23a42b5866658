"""Where a benchmark ran: JAX backend, device kind and host, recorded in every result JSON."""

from __future__ import annotations

import json
import os
import platform
import socket
import sys
import time
from pathlib import Path

import jax
import numpy as np


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; the platform's processor string elsewhere):
    absolute times differ ~3× between the 2-core machines this project runs on."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _cpu_vectors() -> dict:
    """The CPU's vector extensions that XLA:CPU uses (avx2, fma, avx512f; from
    ``/proc/cpuinfo``) and its clock: the EDC kernel ran 1.27·10⁹ samples/s on a host with
    512-bit vectors and 6.5·10⁸ on one without (docs/benchmarks.md §bench_pqrm)."""
    out: dict = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags") and "cpu_vector_extensions" not in out:
                flags = set(line.split(":", 1)[1].split())
                out["cpu_vector_extensions"] = [f for f in ("avx2", "fma", "avx512f", "avx512bw")
                                                if f in flags]
            elif line.startswith("cpu MHz") and "cpu_mhz" not in out:
                out["cpu_mhz"] = float(line.split(":", 1)[1])
    except (OSError, ValueError):
        pass
    return out


def device_info() -> dict:
    """Backend, device kind/count, precision, versions and host load of this process.

    ``backend`` is ``jax.default_backend()`` (``cpu``, ``gpu``/``cuda``, ``tpu``) and
    ``device_kind`` the first device's kind (e.g. ``cpu`` or ``NVIDIA H100 80GB HBM3``), so a
    result file says which hardware its numbers come from.
    """
    devs = jax.devices()
    info = {
        "backend": jax.default_backend(),
        "device_kind": devs[0].device_kind,
        "device_count": len(devs),
        "local_device_count": jax.local_device_count(),
        "process_count": jax.process_count(),
        "x64": bool(jax.config.jax_enable_x64),
        "jax": jax.__version__, "numpy": np.__version__,
        "machine": platform.processor() or platform.machine(),
        "cpu_model": _cpu_model(),
        **_cpu_vectors(),
        "host": socket.gethostname(),
        "python": platform.python_version(),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "cpu_count": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
    try:
        stats = devs[0].memory_stats() or {}
        if "bytes_limit" in stats:
            info["device_memory_bytes"] = int(stats["bytes_limit"])
    except Exception:  # noqa: BLE001  (CPU devices may not report memory)
        pass
    return info


def write_result(result: dict, out: str | os.PathLike, *, process_cpu_s: float | None = None
                 ) -> Path:
    """Write ``result`` to ``out`` (JSON) with ``env`` (:func:`device_info`: where it ran, the
    load now, at the end), the process's total CPU seconds and ``timings`` (every
    ``_timing`` call: its line, wall and CPU seconds); returns the path."""
    try:
        from _timing import CALLS
    except ImportError:  # imported as benchmarks._env
        from benchmarks._timing import CALLS

    result = dict(result)
    if CALLS:
        result.setdefault("timings", [dict(c) for c in CALLS])
    env = device_info()
    env["process_cpu_s"] = round(time.process_time() if process_cpu_s is None
                                 else process_cpu_s, 2)
    result["env"] = {**result.get("env", {}), **env}
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    return path
