"""Where a benchmark ran: JAX backend, device kind and host, recorded in every result JSON."""

from __future__ import annotations

import os
import platform

import jax
import numpy as np


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
