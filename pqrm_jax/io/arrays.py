"""Landmarks, poses, robot-frame observations and camera bearings from CSV or NumPy files.

The array contract (what every loader returns and every mapper takes) is in
:mod:`pqrm_jax.io` and docs/io.md §contract. Every loader raises :class:`DataError` (a
``ValueError``) naming the file and the field (column, key, row) that is wrong: a missing
column, a value that is not a number, NaN or inf, a duplicate or out-of-range id, a wrong
shape.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["DataError", "Observations", "Bearings", "load_landmarks", "load_poses",
           "load_observations", "load_bearings"]


class DataError(ValueError):
    """A data file is malformed; the message names the file and the field."""


class Observations(NamedTuple):
    """Robot-frame landmark positions over T steps, the input of ``pqrm.mapper(...).update``.

    positions: ``[T, M, 2]`` float32, landmark m in the robot frame at step t (0 where unseen).
    visible: ``[T, M]`` bool.
    """

    positions: np.ndarray
    visible: np.ndarray


class Bearings(NamedTuple):
    """Camera images over T steps, field for field a stacked :class:`pqrm_jax.sim.CameraObservation`
    (``protocols.run(qrm.mapper(...), key, init, images)`` steps over its leading axis).

    bearings: ``[T, N]`` float32 radians in ``(-pi, pi]``, counter-clockwise from the heading.
    range_rank: ``[T, N]`` int32, 0 for the nearest visible landmark of the step, -1 unseen.
    visible: ``[T, N]`` bool.
    """

    bearings: np.ndarray
    range_rank: np.ndarray
    visible: np.ndarray


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        with open(path, newline="") as f:
            rows = [r + [f"\0{n}"] for n, r in enumerate(csv.reader(f), 1)
                    if r and not r[0].lstrip().startswith("#")]
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except (UnicodeDecodeError, csv.Error) as e:
        raise DataError(f"{path}: not a readable CSV file ({e})") from None
    if not rows:
        raise DataError(f"{path}: empty file (a header row is required)")
    header = [h.strip().lower() for h in rows[0][:-1]]
    if len(set(header)) != len(header):
        raise DataError(f"{path}: header repeats a column: {rows[0][:-1]}")
    return header, rows[1:]


def _column(path: Path, header: list[str], rows: list[list[str]], names: tuple[str, ...],
            *, integer: bool = False, required: bool = True) -> np.ndarray | None:
    """The first present column of ``names`` as floats (or ints), checked finite."""
    col = next((n for n in names if n in header), None)
    if col is None:
        if required:
            raise DataError(f"{path}: missing column {names[0]!r} (header {header}; "
                            f"accepted names: {', '.join(names)})")
        return None
    j = header.index(col)
    out = []
    for row in rows:
        i = int(row[-1][1:])  # the line number in the file
        if j >= len(row) - 1:
            raise DataError(f"{path}: row {i} has no value in column {col!r}")
        text = row[j].strip()
        try:
            v = float(text)
        except ValueError:
            raise DataError(f"{path}: row {i}, column {col!r}: {text!r} is not a number") from None
        if not math.isfinite(v):
            raise DataError(f"{path}: row {i}, column {col!r}: {text!r} is not finite")
        if integer and v != int(v):
            raise DataError(f"{path}: row {i}, column {col!r}: {text!r} is not an integer")
        out.append(int(v) if integer else v)
    return np.asarray(out, np.int64 if integer else np.float64)


def _read_array(path: Path, key: str) -> np.ndarray:
    try:
        if path.suffix == ".npy":
            return np.load(path, allow_pickle=False)
        with np.load(path, allow_pickle=False) as z:
            if key not in z.files:
                raise DataError(f"{path}: missing array {key!r} (has {sorted(z.files)})")
            return z[key]
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except (ValueError, OSError) as e:
        if isinstance(e, DataError):
            raise
        raise DataError(f"{path}: not a readable NumPy file ({e})") from None


def _check_array(path: Path, key: str, a: np.ndarray, last: int) -> np.ndarray:
    if a.ndim != 2 or a.shape[1] != last:
        raise DataError(f"{path}: {key!r} must have shape (N, {last}), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise DataError(f"{path}: {key!r} must be real numbers, got dtype {a.dtype}")
    bad = ~np.isfinite(a.astype(np.float64))
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise DataError(f"{path}: {key!r} has NaN or inf (first at row {i}, column {j})")
    return a


def _ids_order(path: Path, ids: np.ndarray, n: int, col: str = "id") -> np.ndarray:
    """Row order that sorts ``ids``; they must be exactly ``0 .. n-1`` once each."""
    if len(set(ids.tolist())) != len(ids):
        dup = next(v for v in ids.tolist() if (ids == v).sum() > 1)
        raise DataError(f"{path}: column {col!r} repeats id {dup}")
    if ids.min(initial=0) < 0 or ids.max(initial=-1) >= n:
        raise DataError(f"{path}: column {col!r} must hold the ids 0..{n - 1} once each "
                        f"(got {ids.min()}..{ids.max()})")
    return np.argsort(ids)


def _path(path) -> Path:
    if not isinstance(path, str | Path):
        raise TypeError(f"path must be a str or Path, got {type(path).__name__}")
    return Path(path)


def load_landmarks(path: str | Path, dtype=np.float32) -> np.ndarray:
    """Landmark positions ``[N, 2]`` (world frame) from a CSV, ``.npy`` or ``.npz`` file.

    CSV: a header with columns ``x`` and ``y`` and an optional ``id`` (the ids ``0..N-1`` in
    any order; rows are returned sorted by id, so landmark ``i`` is row ``i``). ``.npy``: an
    ``[N, 2]`` array. ``.npz``: the array ``landmarks``. At least three landmarks (a ternary
    relation needs three).

    Args:
        path: the ``.csv``, ``.npy`` or ``.npz`` file.
        dtype: the floating dtype of the result (float32 by default; float64 for the
            float64 mappers).

    Returns:
        [N, 2] landmark positions, row ``i`` = landmark ``i``.

    Raises:
        DataError: naming the file and the field: a missing column, a non-number or NaN/inf,
            ids not ``0..N-1``, a wrong array shape, fewer than three landmarks.

    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "lm.csv")
    >>> _ = open(p, "w").write("id,x,y\\n1,4,0\\n0,0,0\\n2,2,3\\n")
    >>> load_landmarks(p).tolist()
    [[0.0, 0.0], [4.0, 0.0], [2.0, 3.0]]
    """
    p = _path(path)
    if p.suffix in (".npy", ".npz"):
        a = _check_array(p, "landmarks", _read_array(p, "landmarks"), 2)
    else:
        header, rows = _read_csv(p)
        x = _column(p, header, rows, ("x",))
        y = _column(p, header, rows, ("y",))
        a = np.stack([x, y], axis=1)
        ids = _column(p, header, rows, ("id", "landmark"), integer=True, required=False)
        if ids is not None:
            a = a[_ids_order(p, ids, len(a))]
    if a.shape[0] < 3:
        raise DataError(f"{p}: needs at least 3 landmarks, got {a.shape[0]}")
    return a.astype(dtype)


def load_poses(path: str | Path, dtype=np.float32) -> np.ndarray:
    """Robot poses ``[P, 3]`` = (x, y, heading in radians, counter-clockwise from +x).

    CSV columns ``x``, ``y`` and ``theta`` (or ``yaw`` / ``heading``), rows in time order (an
    optional ``t`` / ``step`` column must then increase). ``.npy``: ``[P, 3]``; ``.npz``: the
    array ``poses``.

    Args:
        path: the ``.csv``, ``.npy`` or ``.npz`` file.
        dtype: the floating dtype of the result.

    Returns:
        [P, 3] poses in time order.

    Raises:
        DataError: naming the file and the field (missing column, NaN/inf, times that do not
            increase, wrong shape, no pose).
    """
    p = _path(path)
    if p.suffix in (".npy", ".npz"):
        a = _check_array(p, "poses", _read_array(p, "poses"), 3)
    else:
        header, rows = _read_csv(p)
        cols = [_column(p, header, rows, n) for n in (("x",), ("y",),
                                                       ("theta", "yaw", "heading"))]
        a = np.stack(cols, axis=1)
        t = _column(p, header, rows, ("t", "step", "time"), required=False)
        if t is not None and np.any(np.diff(t) <= 0):
            i = int(rows[int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1][-1][1:])
            raise DataError(f"{p}: row {i}, column 't/step': times must increase")
    if a.shape[0] < 1:
        raise DataError(f"{p}: no poses")
    return a.astype(dtype)


def _long_table(p: Path, num_landmarks: int, value_cols: tuple[tuple[str, ...], ...]):
    if not isinstance(num_landmarks, int) or isinstance(num_landmarks, bool) \
            or num_landmarks < 3:
        raise ValueError(f"num_landmarks must be an int >= 3, got {num_landmarks!r}")
    header, rows = _read_csv(p)
    step = _column(p, header, rows, ("step", "t"), integer=True)
    lm = _column(p, header, rows, ("landmark", "id"), integer=True)
    vals = [_column(p, header, rows, n) for n in value_cols]
    if len(step) and step.min() < 0:
        raise DataError(f"{p}: column 'step' must be >= 0 (got {step.min()})")
    if len(lm) and (lm.min() < 0 or lm.max() >= num_landmarks):
        raise DataError(f"{p}: column 'landmark' must lie in 0..{num_landmarks - 1} "
                        f"(got {lm.min()}..{lm.max()})")
    pairs = step * num_landmarks + lm
    if len(np.unique(pairs)) != len(pairs):
        k = next(v for v in pairs.tolist() if (pairs == v).sum() > 1)
        raise DataError(f"{p}: step {k // num_landmarks} lists landmark "
                        f"{k % num_landmarks} twice (columns 'step', 'landmark')")
    T = int(step.max()) + 1 if len(step) else 0
    return T, step, lm, vals


def load_observations(path: str | Path, num_landmarks: int) -> Observations:
    """Robot-frame landmark measurements for PQRM (``pqrm.mapper(...).update``).

    CSV in long form, one row per seen landmark: ``step, landmark, x, y`` with ``x, y`` the
    landmark in the robot frame (x ahead, y left). Steps are ``0..T-1`` (a step without rows
    sees nothing).

    Args:
        path: the CSV file.
        num_landmarks: N, the number of landmarks of the map (ids ``0..N-1``; ≥ 3).

    Returns:
        :class:`Observations` with ``pos`` [T, N, 2] (robot frame) and ``visible`` [T, N].

    Raises:
        DataError: naming the file and the column (missing, NaN, negative step, an id out of
            range, a landmark listed twice in one step).
        ValueError: when ``num_landmarks`` is not an int ≥ 3.
    """
    p = _path(path)
    T, step, lm, (x, y) = _long_table(p, num_landmarks, (("x",), ("y",)))
    pos = np.zeros((T, num_landmarks, 2), np.float32)
    vis = np.zeros((T, num_landmarks), bool)
    pos[step, lm, 0], pos[step, lm, 1] = x, y
    vis[step, lm] = True
    return Observations(pos, vis)


def load_bearings(path: str | Path, num_landmarks: int) -> Bearings:
    """Camera bearings for the camera QRM (``qrm.mapper(...).update``, M §IV).

    CSV in long form: ``step, landmark, bearing`` (radians, counter-clockwise from the
    heading; wrapped into ``(-pi, pi]``) and either ``range`` (any unit: only the order is
    used) or ``rank`` (0 = nearest of the step). Ties in range are broken by landmark id, as
    in :func:`pqrm_jax.sim.camera`.

    Args:
        path: the CSV file.
        num_landmarks: N, the number of landmarks of the map (ids ``0..N-1``; ≥ 3).

    Returns:
        :class:`Bearings` with ``bearings`` [T, N] (radians), ``range_rank`` [T, N] (−1 where
        unseen) and ``visible`` [T, N].

    Raises:
        DataError: naming the file and the column (missing, NaN, negative range, ranks that
            are not ``0..k-1`` in a step, an id out of range, a landmark listed twice).
        ValueError: when ``num_landmarks`` is not an int ≥ 3.
    """
    p = _path(path)
    header, _ = _read_csv(p)
    order_col = ("range",) if "range" in header else ("rank", "range_rank")
    T, step, lm, (b, order) = _long_table(p, num_landmarks, (("bearing",), order_col))
    if order_col[0] == "range" and np.any(order < 0):
        raise DataError(f"{p}: column 'range' must be >= 0")
    bear = np.zeros((T, num_landmarks), np.float32)
    rank = np.full((T, num_landmarks), -1, np.int32)
    vis = np.zeros((T, num_landmarks), bool)
    wrapped = np.pi - np.mod(np.pi - b, 2 * np.pi)  # (-pi, pi]
    bear[step, lm] = wrapped
    vis[step, lm] = True
    for t in range(T):
        sel = np.flatnonzero(step == t)
        srt = sel[np.lexsort((lm[sel], order[sel]))]
        if order_col[0] != "range":
            got = order[srt].astype(int).tolist()
            if got != list(range(len(sel))):
                raise DataError(f"{p}: step {t}: column 'rank' must hold 0..{len(sel) - 1} "
                                f"once each, got {sorted(got)}")
        rank[t, lm[srt]] = np.arange(len(sel), dtype=np.int32)
    return Bearings(bear, rank, vis)
