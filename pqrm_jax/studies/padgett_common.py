"""Shared words of the Padgett Monte Carlo study and its report (P §2.3.1).

The study (:mod:`.padgett_mc`) and its report (:mod:`._padgett_report`) both import from here,
so neither imports the other.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["SIGMA_E", "BD_BINS", "boundary_distance", "load_done", "load_results"]

#: Standard deviation of a landmark coordinate uniform on a 100 m side (P §2.3.1).
SIGMA_E = 100.0 / math.sqrt(12.0)

BD_BINS = np.array([0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, np.inf])


def boundary_distance(xy: np.ndarray) -> np.ndarray:
    """Distance (in |AB| units) of C = (α, β) to the nearest EDC boundary (SPEC §2.1)."""
    a, b = xy[:, 0], xy[:, 1]
    da = np.hypot(a, b)  # to A
    db = np.hypot(a, b - 1.0)  # to B
    cands = [np.abs(a), np.abs(b), np.abs(b - 0.5), np.abs(b - 1.0), np.abs(da - 1.0),
             np.abs(db - 1.0)]
    return np.min(np.stack(cands), axis=0)


def load_done(out: Path) -> list[dict]:
    """The finished level summaries in ``out/levels.jsonl`` (a torn last line is ignored)."""
    path = out / "levels.jsonl"
    if not path.exists():
        return []
    lines = []
    for raw in path.read_text().splitlines():
        raw = raw.strip()
        if not raw:
            continue
        try:
            line = json.loads(raw)
        except json.JSONDecodeError:  # a torn last line from a kill: ignore, recompute
            break
        if (out / f"level_{line['level']:02d}.npz").exists():
            lines.append(line)
    return lines


def load_results(out: Path) -> tuple[dict, list[dict], dict[int, dict]]:
    """``(config, level summaries, level arrays)`` of a study directory."""
    cfg = json.loads((out / "config.json").read_text())
    lines = sorted(load_done(out), key=lambda d: d["level"])
    arrays = {}
    for line in lines:
        with np.load(out / f"level_{line['level']:02d}.npz") as z:
            arrays[line["level"]] = {k: z[k] for k in z.files}
    return cfg, lines, arrays
