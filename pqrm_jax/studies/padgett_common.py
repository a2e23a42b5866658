"""Shared words of the Padgett Monte Carlo study and its report (P §2.3.1).

The study (:mod:`.padgett_mc`) and its report (:mod:`._padgett_report`) both import from here,
so neither imports the other.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["SIGMA_E", "BD_BINS", "LINE_FIELDS", "boundary_distance", "level_check",
           "load_done", "load_results", "npz_required"]

#: Standard deviation of a landmark coordinate uniform on a 100 m side (P §2.3.1).
SIGMA_E = 100.0 / math.sqrt(12.0)

BD_BINS = np.array([0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, np.inf])


def boundary_distance(xy: np.ndarray) -> np.ndarray:
    """Distance (in |AB| units) of C = (α, β) to the nearest EDC boundary.

    The boundaries are those of docs/decisions.md §2.1.
    """
    a, b = xy[:, 0], xy[:, 1]
    da = np.hypot(a, b)  # to A
    db = np.hypot(a, b - 1.0)  # to B
    cands = [np.abs(a), np.abs(b), np.abs(b - 0.5), np.abs(b - 1.0), np.abs(da - 1.0),
             np.abs(db - 1.0)]
    return np.min(np.stack(cands), axis=0)


#: Fields every ``levels.jsonl`` line must have.
LINE_FIELDS = ("level", "tag", "sigma_r", "runs", "reps")


def level_check(n_levels: int):
    """A check of one ``levels.jsonl`` line: level in ``[0, n_levels)``, reps of dicts."""
    def ok(line: dict) -> bool:
        lv = line["level"]
        return (isinstance(lv, int) and 0 <= lv < n_levels and isinstance(line["reps"], dict)
                and all(isinstance(v, dict) for v in line["reps"].values()))
    return ok


def npz_required(reps) -> tuple[str, ...]:
    """The arrays a ``level_XX.npz`` of representations ``reps`` must hold."""
    return tuple(f"{r}/{k}" for r in reps for k in ("entropy", "error", "p_ml", "neighbor",
                                                     "confusion")) + ("err/num_errors",)


def load_done(out: Path, n_levels: int | None = None, reps=None) -> list[dict]:
    """The finished levels of ``out``: a valid ``levels.jsonl`` line whose npz reads in full.

    Bad lines (torn, garbage, ``null``, missing fields) and corrupt npz files are named in a
    :class:`~pqrm_jax.studies.store.CorruptRecordWarning` and left out (recomputed by the
    study). ``reps`` defaults to Padgett's six representations.
    """
    import warnings

    from .store import CorruptRecordWarning, read_jsonl, read_npz

    if reps is None:
        from .. import calculi

        reps = calculi.PADGETT_REPRESENTATIONS
    n = n_levels if n_levels is not None else 10**6
    done, problems = read_jsonl(out / "levels.jsonl", key=lambda r: r["level"],
                                required=LINE_FIELDS, check=level_check(n))
    for msg in problems:
        warnings.warn(f"{msg}; that level is recomputed", CorruptRecordWarning, stacklevel=2)
    req = npz_required(reps)
    return [line for k, line in sorted(done.items())
            if read_npz(out / f"level_{k:02d}.npz", req) is not None]


def load_results(out: Path) -> tuple[dict, list[dict], dict[int, dict]]:
    """``(config, level summaries, level arrays)`` of a study directory; corrupt levels skipped.

    Raises :class:`~pqrm_jax.studies.store.StudyError` when ``out`` holds no result.
    """
    from .store import StudyError, read_npz

    try:
        cfg = json.loads((out / "config.json").read_text())
    except FileNotFoundError:
        raise StudyError(f"{out} holds no padgett-mc results (no config.json)") from None
    except json.JSONDecodeError as exc:
        raise StudyError(f"{out / 'config.json'} is corrupt ({exc})") from None
    reps = tuple(cfg["representations"]) if "representations" in cfg else None
    lines = load_done(out, len(cfg.get("levels_sigma_r", [])) or None, reps)
    arrays = {}
    for line in lines:
        arrays[line["level"]] = read_npz(out / f"level_{line['level']:02d}.npz")
    if not lines:
        raise StudyError(f"{out} holds no finished padgett-mc level; run the study first")
    return cfg, lines, arrays
