"""One result store for every study: lock, study marker, config guard, atomic verified records.

A study directory (``--out``) holds one study. :meth:`Store.open` makes it safe to run, kill,
resume and inspect:

* **lock** — an exclusive ``fcntl.flock`` on ``out/.lock`` is held while the store is open, so
  a second process on the same directory is refused with a message instead of computing
  every unit twice and appending duplicates. (A multi-process study,
  :mod:`pqrm_jax.studies.distributed`, opens the store in process 0 only.)
* **study marker** — ``out/study.json`` names the study; a directory of another study, or a
  non-empty directory of files the study does not know, is refused.
* **config guard** — ``out/config.json`` holds every setting that changes results, plus the
  precision (``"precision": "float32" | "float64"``, from ``jax_enable_x64``); resuming with a
  different value of any field is refused, naming the fields. Fields in ``selection`` only
  choose which units are computed and are merged (lists: union; numbers: max).
* **atomic writes** — every file goes through a temp file in the same directory and
  ``os.replace``: a kill leaves the old file or the new one, never half of one.
* **verified reads** — :meth:`Store.read_npz` reads every array (zip CRC checked),
  :meth:`Store.read_json`, :meth:`Store.read_csv` and :meth:`Store.records` parse and check
  each record. A truncated,
  empty or garbage file, a torn JSONL line, or a valid-JSON line of the wrong shape (``null``,
  ``{"lvl": 2}``) is named in a :class:`CorruptRecordWarning` (file, and line number for
  JSONL); a bad file is moved aside (``*.corrupt``), a bad line is dropped when the file is
  rewritten, and the unit counts as not done, so it alone is recomputed.
* **older directories** — an unmarked directory holding only files an older version of the
  study wrote (``legacy`` globs) is adopted; its recorded config (``legacy_config``) is
  guarded, fields it never recorded (``legacy_assume``, ``precision``) are assumed with a
  warning. Temp files of killed writers are removed when a store is opened.
* **tidy results** — :meth:`Store.write_results_csv` writes ``results.csv`` with one row per
  unit × metric (columns ``study, unit, metric, value``) that ``pandas.read_csv`` reads as is.

A study uses it in a few lines::

    with Store.open(out, "my-study", {"runs": 10, "seed": 0}, selection=("runs",)) as st:
        log = st.records("results.jsonl", key=lambda r: r["unit"], required=("unit", "x"))
        for unit in range(10):
            if unit not in log:
                log.add({"unit": unit, "x": float(compute(unit))})
        st.write_results_csv(tidy_rows(log.values(), unit=lambda r: r["unit"],
                                       skip=("unit",)))

>>> import tempfile
>>> d = Path(tempfile.mkdtemp()) / "s"
>>> with Store.open(d, "demo", {"runs": 2}, selection=("runs",)) as st:
...     log = st.records("r.jsonl", key=lambda r: r["unit"], required=("unit", "x"))
...     for u in range(2):
...         _ = log.add({"unit": u, "x": u / 2})
...     rows = tidy_rows(log.values(), unit=lambda r: r["unit"], skip=("unit",))
...     path = st.write_results_csv(rows)
>>> print(path.read_text().strip())
study,unit,metric,value
demo,0,x,0.0
demo,1,x,0.5
>>> Store.open(d, "other", {})  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
pqrm_jax.studies.store.StoreError: ... holds a 'demo' study, not 'other'; use another --out
"""

from __future__ import annotations

import csv
import fnmatch
import io
import json
import math
import os
import shutil
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

try:  # POSIX; on other systems the lock is advisory-only (not taken)
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None

MARKER = "study.json"
CONFIG = "config.json"
STORE_VERSION = 1


class StudyError(RuntimeError):
    """A study cannot run or finish as asked (bad directory, failed dependency, ...).

    The CLI prints the message on one line and exits with code 2.
    """


class StoreError(StudyError):
    """The study directory is locked, holds another study or another configuration."""


class CorruptRecordWarning(UserWarning):
    """A stored record was unreadable or malformed; it was set aside and will be recomputed."""


def precision() -> str:
    """``"float64"`` when ``jax_enable_x64`` is on, else ``"float32"`` (results differ)."""
    import jax

    return "float64" if jax.config.jax_enable_x64 else "float32"


# ------------------------------------------------------------------------------------------
# atomic writes
# ------------------------------------------------------------------------------------------


def atomic_write_bytes(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temp file in the same directory and ``os.replace``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def atomic_write_text(path: Path, text: str) -> Path:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    return atomic_write_bytes(path, text.encode())


def atomic_write_json(path: Path, obj: Any, indent: int | None = 1) -> Path:
    """:func:`atomic_write_bytes` of ``obj`` as JSON (NaN written as JSON ``NaN``)."""
    return atomic_write_text(path, json.dumps(obj, indent=indent))


def atomic_write_npz(path: Path, arrays: dict[str, Any], compressed: bool = True) -> Path:
    """:func:`atomic_write_bytes` of ``arrays`` as an ``.npz`` archive."""
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


# ------------------------------------------------------------------------------------------
# verified reads (usable without a store, e.g. for --report-only)
# ------------------------------------------------------------------------------------------


def _quarantine(path: Path, why: str) -> None:
    """Warn naming ``path`` and move it aside to ``path.corrupt`` (kept for inspection)."""
    warnings.warn(f"{path}: {why}; set aside as {path.name}.corrupt (the study recomputes it)",
                  CorruptRecordWarning, stacklevel=3)
    try:
        os.replace(path, path.with_name(path.name + ".corrupt"))
    except OSError:  # pragma: no cover - read-only directory: leave it
        pass


def read_npz(path: Path, required: Iterable[str] = (), *, quarantine: bool = True
             ) -> dict[str, np.ndarray] | None:
    """All arrays of ``path``, or ``None`` when it is missing or corrupt.

    Every array is read in full (the zip CRC is checked), and the keys in ``required`` must
    be there. A corrupt file (truncated, empty, garbage, missing keys) is named in a
    :class:`CorruptRecordWarning` and, with ``quarantine``, moved aside.
    """
    path = Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: np.asarray(z[k]) for k in z.files}
        missing = [k for k in required if k not in out]
        if missing:
            raise KeyError(f"missing arrays {missing[:3]}")
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError, zlib.error) as exc:
        if quarantine:
            _quarantine(path, f"corrupt npz ({type(exc).__name__}: {exc})")
        else:
            warnings.warn(f"{path}: corrupt npz ({exc})", CorruptRecordWarning, stacklevel=2)
        return None
    return out


def _check_record(rec: Any, required: Iterable[str], check: Callable[[dict], bool] | None
                  ) -> str | None:
    if not isinstance(rec, dict):
        return f"not a JSON object ({type(rec).__name__})"
    missing = [k for k in required if k not in rec]
    if missing:
        return f"missing fields {missing}"
    if check is not None:
        try:
            ok = check(rec)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            return f"bad record ({type(exc).__name__}: {exc})"
        if not ok:
            return "record fails its study's check"
    return None


def read_json(path: Path, required: Iterable[str] = (),
              check: Callable[[dict], bool] | None = None, *, quarantine: bool = True
              ) -> dict | None:
    """The JSON object in ``path``, or ``None`` when missing, torn, garbage or malformed."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        rec = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        why = f"torn or garbage JSON ({exc})"
    else:
        why = _check_record(rec, required, check)
        if why is None:
            return rec
    if quarantine:
        _quarantine(path, why)
    return None


def read_jsonl(path: Path, key: Callable[[dict], Any], required: Iterable[str] = (),
               check: Callable[[dict], bool] | None = None) -> tuple[dict, list[str]]:
    """(records by key, problems) of a JSONL file; bad lines are skipped, each one named.

    A line that is not JSON (torn by a kill, garbage), not an object, lacks a ``required``
    field or fails ``check`` is reported in ``problems`` as ``"path:line: why"``; the lines
    after it are still read. A repeated key keeps the first record.
    """
    path = Path(path)
    good: dict = {}
    bad: list[str] = []
    if not path.exists():
        return good, bad
    for no, raw in enumerate(path.read_text(errors="replace").splitlines(), 1):
        raw = raw.strip()
        if not raw:
            continue
        try:
            rec = json.loads(raw)
        except json.JSONDecodeError as exc:
            bad.append(f"{path}:{no}: torn or garbage line ({exc.msg})")
            continue
        why = _check_record(rec, required, check)
        if why is None:
            try:
                k = key(rec)
                hash(k)
            except (KeyError, TypeError, ValueError) as exc:
                why = f"no usable key ({type(exc).__name__}: {exc})"
        if why is not None:
            bad.append(f"{path}:{no}: {why}")
            continue
        if k in good:
            bad.append(f"{path}:{no}: duplicate record for {k!r} (first kept)")
            continue
        good[k] = rec
    return good, bad


def read_csv(path: Path, fields: Iterable[str], check: Callable[[list[dict]], bool] | None = None,
             *, quarantine: bool = True) -> list[dict] | None:
    """The rows of a CSV file (dicts of strings), or ``None`` when missing, torn or malformed.

    The header must be exactly ``fields``; a last line without its line end or a row with a
    missing or extra cell (torn), an undecodable file or rows failing ``check`` (e.g. a wrong
    row count) make the whole file corrupt: it is named in a :class:`CorruptRecordWarning`
    and, with ``quarantine``, moved aside, so the unit it holds is recomputed.
    """
    path = Path(path)
    if not path.exists():
        return None
    fields = list(fields)
    why = None
    try:
        with path.open(newline="") as fh:
            text = fh.read()
        reader = csv.DictReader(io.StringIO(text, newline=""))
        rows = list(reader)
        header = reader.fieldnames
    except (UnicodeDecodeError, csv.Error) as exc:
        why = f"torn or garbage CSV ({type(exc).__name__}: {exc})"
    else:
        if text and not text.endswith("\n"):
            why = "the last line is cut (torn)"
        elif header != fields:
            why = f"header {header} is not {fields}"
        elif any(None in r or any(v is None for v in r.values()) for r in rows):
            why = "a row with missing or extra cells (torn)"
        elif check is not None:
            try:
                ok = check(rows)
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                why = f"bad rows ({type(exc).__name__}: {exc})"
            else:
                why = None if ok else "rows fail their study's check"
    if why is None:
        return rows
    if quarantine:
        _quarantine(path, why)
    else:
        warnings.warn(f"{path}: {why}", CorruptRecordWarning, stacklevel=2)
    return None


def csv_text(fields: Iterable[str], rows: Iterable[dict]) -> str:
    """The CSV text (header ``fields``, ``\\r\\n`` line ends as :mod:`csv` writes) of ``rows``."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(fields), extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def atomic_savefig(fig: Any, path: Path, **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically (rendered in memory, then :func:`atomic_write_bytes`).

    The format is taken from the suffix of ``path``; ``kwargs`` go to ``fig.savefig``.
    """
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format=kwargs.pop("format", path.suffix.lstrip(".") or "png"), **kwargs)
    return atomic_write_bytes(path, buf.getvalue())


# ------------------------------------------------------------------------------------------
# tidy results
# ------------------------------------------------------------------------------------------


#: Top-level record fields that hold measured times (``fnmatch`` patterns): they depend on the
#: machine and its load, so :class:`Records` keeps them in a sidecar ``NAME.times.jsonl`` and
#: :func:`tidy_rows` leaves them out of ``results.csv``: two identical runs give byte-identical
#: results files.
MEASURED = ("*_s", "seconds", "wall", "elapsed")


def is_measured(name: str, measured: Iterable[str] = MEASURED) -> bool:
    """True when the field ``name`` holds a measured time (matches a ``measured`` pattern).

    >>> [is_measured(k) for k in ("explore_s", "seconds", "sigmas", "steps", "wall")]
    [True, True, False, False, True]
    """
    return any(fnmatch.fnmatchcase(name, g) for g in measured)


def flatten_metrics(obj: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
    """``(metric, value)`` pairs of the numbers in a nested dict/list (names joined by ``/``).

    Strings and ``None`` are skipped; booleans become 0/1.

    >>> list(flatten_metrics({"a": 1, "b": {"c": [2, 3]}, "tag": "x", "ok": True}))
    [('a', 1.0), ('b/c/0', 2.0), ('b/c/1', 3.0), ('ok', 1.0)]
    """
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from flatten_metrics(v, f"{prefix}/{k}" if prefix else str(k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from flatten_metrics(v, f"{prefix}/{i}" if prefix else str(i))
    elif isinstance(obj, (bool, np.bool_)):
        yield prefix, float(obj)
    elif isinstance(obj, (int, float, np.integer, np.floating)):
        yield prefix, float(obj)


def tidy_rows(records: Iterable[dict], unit: Callable[[dict], Any],
              skip: Iterable[str] = (), measured: Iterable[str] = MEASURED
              ) -> list[tuple[str, str, float]]:
    """``(unit, metric, value)`` rows of records, one per number (``skip``: top-level keys).

    Top-level fields matching ``measured`` (:data:`MEASURED`, wall times) are left out, so
    ``results.csv`` does not depend on the machine's speed; pass ``measured=()`` to keep them.
    """
    skip = set(skip)
    measured = tuple(measured)
    rows = []
    for rec in records:
        u = str(unit(rec))
        rows += [(u, m, v) for m, v in flatten_metrics(
            {k: x for k, x in rec.items() if k not in skip and not is_measured(k, measured)})]
    return rows


# ------------------------------------------------------------------------------------------
# the store
# ------------------------------------------------------------------------------------------


class Records:
    """The valid records of one JSONL file of a store, by key; :meth:`add` appends one line.

    :meth:`add` appends one line (one ``write`` on an ``O_APPEND`` descriptor: O(1) per
    record, no whole-file rewrite); a kill mid-line leaves a torn last line that the next
    open names, drops and repairs (the file is rewritten atomically once then). Replacing a
    record of an existing key, :meth:`discard` and that repair rewrite the file through a temp
    file. Fields matching ``measured`` (default :data:`MEASURED`: wall times) go to the
    sidecar ``NAME.times.jsonl`` instead, so the results file holds only results; they are
    merged back into the records this object returns.
    """

    def __init__(self, path: Path, key: Callable[[dict], Any], required: Iterable[str],
                 check: Callable[[dict], bool] | None, measured: Iterable[str] = MEASURED):
        self.path, self.key = Path(path), key
        self.measured = tuple(measured)
        self.times_path = self.path.with_name(self.path.stem + ".times.jsonl")
        times, _ = read_jsonl(self.times_path, key=lambda r: r["key"], required=("key",))
        raw, problems = read_jsonl(self.path, key)
        self.done: dict = {}
        for k, rec in raw.items():
            merged = dict(rec, **{f: v for f, v in times.get(repr(k), {}).items()
                                  if f != "key"})
            why = _check_record(merged, required, check)
            if why is not None:
                problems.append(f"{self.path}: record {k!r}: {why}")
                continue
            self.done[k] = merged
        self._file_keys = list(raw)  # the keys in file order (appends go to the end)
        for p in problems:
            warnings.warn(f"{p}; that unit is recomputed", CorruptRecordWarning, stacklevel=3)
        torn = self.path.exists() and self.path.stat().st_size > 0 \
            and not self.path.read_bytes().endswith(b"\n")
        if problems or torn or any(self._split(r)[1] for r in raw.values()):
            self._save()

    def __contains__(self, k: Any) -> bool:
        return k in self.done

    def __len__(self) -> int:
        return len(self.done)

    def get(self, k: Any) -> dict | None:
        """The record with key ``k`` or ``None``."""
        return self.done.get(k)

    def discard(self, k: Any) -> None:
        """Forget the record ``k`` (e.g. its arrays were corrupt) and persist."""
        if self.done.pop(k, None) is not None:
            self._save()

    def values(self) -> list[dict]:
        """The records sorted by key (insertion order if keys do not sort)."""
        try:
            return [self.done[k] for k in sorted(self.done)]
        except TypeError:
            return list(self.done.values())

    def _split(self, rec: dict) -> tuple[dict, dict]:
        res = {f: v for f, v in rec.items() if not is_measured(f, self.measured)}
        return res, {f: v for f, v in rec.items() if is_measured(f, self.measured)}

    def add(self, rec: dict) -> dict:
        """Store ``rec``: append its line (a record with the same key is replaced)."""
        copy = json.loads(json.dumps(rec))
        k = self.key(copy)
        replace = k in self.done
        self.done[k] = copy
        if replace:
            self._save()
            return rec
        res, times = self._split(copy)
        if times:
            _append_line(self.times_path, json.dumps({"key": repr(k), **times}))
        _append_line(self.path, json.dumps(res))
        self._file_keys.append(k)
        return rec

    def tidy(self) -> None:
        """Rewrite the file in key order if appends left it in another order (once, at the
        store's close), so a resumed run's file equals an uninterrupted run's byte for byte."""
        order = [self.key(r) for r in self.values()]
        if self._file_keys != order:
            self._save()

    def _save(self) -> None:
        recs = self.values()
        self._file_keys = [self.key(r) for r in recs]
        parts = [self._split(r) for r in recs]
        atomic_write_text(self.path, "".join(json.dumps(a) + "\n" for a, _ in parts))
        lines = [json.dumps({"key": repr(self.key(r)), **t}) + "\n"
                 for r, (_, t) in zip(recs, parts, strict=True) if t]
        if lines or self.times_path.exists():
            atomic_write_text(self.times_path, "".join(lines))


def _append_line(path: Path, line: str) -> None:
    """Append ``line`` and a newline to ``path`` with one ``write`` (``O_APPEND``)."""
    data = (line + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        while data:
            data = data[os.write(fd, data):]
    finally:
        os.close(fd)


#: Config fields that hold explanatory prose (each knob's reason), not settings: stored in
#: ``config.json`` for the reader but never compared by the config guard, so rewording a
#: reason in a new version does not refuse existing directories.
PROSE = ("reasons",)


def canonical(value: Any) -> Any:
    """``value`` in a form where equal settings compare equal: NaN equals NaN, ``1 == 1.0``,
    tuples are lists, dict keys are strings (as in JSON).

    >>> nan = float("nan")
    >>> canonical({"a": nan, "b": (1, 2.0)}) == canonical({"b": [1.0, 2], "a": nan})
    True
    """
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)):
        v = float(value)
        if math.isnan(v):
            return "NaN"
        return v
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [canonical(v) for v in value]
    return repr(value)


def config_diff(have: dict, want: dict, ignore: Iterable[str] = ()) -> list[str]:
    """The sorted top-level keys whose values differ canonically (:func:`canonical`).

    >>> config_diff({"x": float("nan"), "y": 1, "reasons": "a"}, {"x": float("nan"), "y": 2,
    ...             "reasons": "b"}, ignore=("reasons",))
    ['y']
    """
    ignore = set(ignore)
    return sorted(k for k in set(have) | set(want)
                  if k not in ignore and canonical(have.get(k)) != canonical(want.get(k)))


def _short(value: Any, width: int = 24) -> str:
    text = "(absent)" if value is _ABSENT else repr(value)
    return text if len(text) <= width else text[:width - 1] + "…"


_ABSENT = object()


def _describe_diff(have: dict, want: dict, keys: list[str], most: int = 4) -> str:
    """A short text of differing keys, ``key: V there, W asked`` (values cut), ``most`` shown."""
    parts = [f"{k}: {_short(have.get(k, _ABSENT))} there, {_short(want.get(k, _ABSENT))} "
             "asked" for k in keys[:most]]
    more = f"; and {len(keys) - most} more: {', '.join(keys[most:])}" if len(keys) > most else ""
    return "; ".join(parts) + more


class Store:
    """An open study directory (see the module doc); use :meth:`open`, close when done."""

    def __init__(self, out: Path, study: str, config: dict, fds: list[int]):
        self.out, self.study, self.config, self._fds = out, study, config, fds
        self._records: list[Records] = []

    # -- opening -------------------------------------------------------------------------

    @classmethod
    def open(cls, out: str | Path, study: str, config: dict | None, *,
             selection: tuple[str, ...] = (), legacy: tuple[str, ...] = (),
             fresh: bool = False,
             legacy_config: str | None = None, legacy_assume: tuple[str, ...] = (),
             advice: str = "use another --out") -> Store:
        """Lock ``out``, check it holds ``study`` and guard ``config``; returns the store.

        Args:
            out: the study directory (created if missing).
            study: the study's name, stored in ``study.json``.
            config: every result-changing setting (JSON-able); ``"precision"`` is added.
                ``None`` attaches to an existing study (e.g. ``--report-only``) and raises
                :class:`StoreError` when ``out`` holds none.
            selection: config fields that only choose which units run (merged on resume).
            legacy: glob patterns of files an older version of this study wrote without a
                marker; a directory holding only such files is adopted, any other
                non-empty unmarked directory is refused.
            fresh: delete the stored results of this study first (after the checks).
            legacy_config: the file an older version kept its config in (e.g.
                ``"meta.json"``); read as the stored config of an adopted directory.
            legacy_assume: fields an older version did not record (``"precision"`` always):
                in an adopted directory they are assumed to match, with a warning.
            advice: appended to refusals.

        Raises:
            StoreError: ``out`` is a file or not writable, is locked by another process,
                holds another study or unknown files, or a different configuration.
        """
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise StoreError(f"--out {out} is an existing file, not a directory; {advice}")
        if config is None and not out.is_dir():
            raise StoreError(f"--out {out} does not exist: no {study} results to read")
        try:
            out.mkdir(parents=True, exist_ok=True)
            fds = cls._lock(out)
        except PermissionError as exc:
            raise StoreError(f"--out {out} is not writable ({exc.strerror}); {advice}") \
                from None
        except OSError as exc:
            raise StoreError(f"--out {out} cannot be used ({exc.strerror or exc}); {advice}") \
                from None
        try:
            legacy_dir = cls._check_marker(out, study, legacy, advice)
            cls._clean_tmp(out)
            if config is None:
                try:
                    cfg = json.loads((out / CONFIG).read_text())
                except FileNotFoundError:
                    raise StoreError(f"{out} holds no {study} results (no {CONFIG}); run the "
                                     "study first") from None
                except json.JSONDecodeError as exc:
                    raise StoreError(f"{out / CONFIG} is corrupt ({exc})") from None
            else:
                if fresh:
                    cls._wipe(out)
                cfg = dict(config, precision=precision())
                if legacy_dir and legacy_config and not (out / CONFIG).exists() \
                        and (out / legacy_config).exists():
                    shutil.copyfile(out / legacy_config, out / CONFIG)
                assume = ("precision", *legacy_assume) if legacy_dir else ()
                cfg = cls._guard(out, cfg, selection, assume, advice)  # checks, writes nothing
                # the marker first: a kill between the two files leaves a marked directory
                # (resumable, --fresh wipes it), never an unmarked one holding a config.json
                atomic_write_json(out / MARKER, {"study": study,
                                                 "store_version": STORE_VERSION})
                atomic_write_json(out / CONFIG, cfg)
        except BaseException:
            cls._unlock(fds)
            raise
        return cls(out, study, cfg, fds)

    @classmethod
    def wipe(cls, out: str | Path, study: str, *, legacy: tuple[str, ...] = (),
             advice: str = "use another --out") -> None:
        """``--fresh`` for a study that opens its store later: lock ``out``, check that it
        holds ``study`` (or is empty / an adoptable older directory), delete its contents.

        Raises:
            StoreError: locked by another process, or a directory of another study.
        """
        out = Path(out)
        if not out.is_dir():
            return
        fds = cls._lock(out)
        try:
            cls._check_marker(out, study, legacy, advice)
            cls._wipe(out)
        finally:
            cls._unlock(fds)

    @staticmethod
    def _lock(out: Path) -> list[int]:
        if fcntl is None:  # pragma: no cover
            return []
        fd = os.open(out / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise StoreError(f"{out} is in use by another process running it (lock "
                             f"{out / '.lock'} is held); wait for it to finish or use another "
                             "--out") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        return [fd]

    @staticmethod
    def _unlock(fds: list[int]) -> None:
        for fd in fds:
            try:
                os.close(fd)  # releases the flock
            except OSError:  # pragma: no cover
                pass
        fds.clear()

    @staticmethod
    def _check_marker(out: Path, study: str, legacy: tuple[str, ...], advice: str) -> bool:
        """True when ``out`` is an unmarked directory adopted from an older version."""
        marker = out / MARKER
        if marker.exists():
            try:
                have = json.loads(marker.read_text())["study"]
            except (json.JSONDecodeError, KeyError, TypeError) as exc:
                raise StoreError(f"{marker} is corrupt ({exc!r}); {advice}") from None
            if have != study:
                raise StoreError(f"{out} holds a {have!r} study, not {study!r}; {advice}")
            return False
        entries = [p.name for p in out.iterdir() if not p.name.startswith(".")]
        if entries == [CONFIG]:  # an older version killed between config.json and the marker
            return False
        unknown = [n for n in entries if not any(fnmatch.fnmatch(n, g) for g in legacy)]
        if unknown:
            raise StoreError(f"{out} is not empty and holds files that are not from a {study} "
                             f"study (e.g. {sorted(unknown)[0]!r}); {advice}")
        return bool(entries)

    @staticmethod
    def _clean_tmp(out: Path) -> None:
        """Remove temp files left by killed writers (their process is gone)."""
        for p in out.rglob(".*.tmp-*"):
            try:
                pid = int(p.name.rsplit("-", 1)[1])
                os.kill(pid, 0)  # alive (another process writing): keep
            except ProcessLookupError:
                p.unlink(missing_ok=True)
            except (ValueError, PermissionError, OSError):
                continue

    @staticmethod
    def _wipe(out: Path) -> None:
        for p in out.iterdir():
            if p.name.startswith(".lock"):
                continue
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()

    @staticmethod
    def _guard(out: Path, cfg: dict, selection: tuple[str, ...], assume: tuple[str, ...],
               advice: str) -> dict:
        cfg = json.loads(json.dumps(cfg))
        path = out / CONFIG
        merged = dict(cfg)
        if path.exists():
            try:
                have = json.loads(path.read_text())
                if not isinstance(have, dict):
                    raise ValueError("not a JSON object")
            except (json.JSONDecodeError, ValueError) as exc:
                raise StoreError(f"{path} is corrupt ({exc}); {advice} or --fresh") from None
            for k in assume:
                if k not in have and k in cfg:
                    warnings.warn(f"{path} was written before studies recorded {k!r}; "
                                  f"assuming {cfg[k]!r}", stacklevel=4)
                    have[k] = cfg[k]
            diff = config_diff(have, cfg, ignore=(*selection, *PROSE))
            if diff:
                raise StoreError(f"{out} holds a study with a different config "
                                 f"({_describe_diff(have, cfg, diff)}); {advice}")
            for k in selection:
                a, b = have.get(k), cfg.get(k)
                if isinstance(a, list) and isinstance(b, list):
                    union = a + [x for x in b if x not in a]
                    numeric = all(isinstance(x, (int, float)) for x in union)
                    merged[k] = sorted(union) if numeric else union
                elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
                    merged[k] = max(a, b)
        return merged

    # -- use -----------------------------------------------------------------------------

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Put the record files in key order (:meth:`Records.tidy`) and release the lock
        (also released when the process dies)."""
        try:
            if self._fds:
                for rec in self._records:
                    rec.tidy()
        finally:
            self._records.clear()
            self._unlock(self._fds)

    def path(self, name: str) -> Path:
        """``out/name`` (parent folders created)."""
        p = self.out / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_text(self, name: str, text: str) -> Path:
        """Atomically write ``out/name``."""
        return atomic_write_text(self.path(name), text)

    def write_json(self, name: str, obj: Any, indent: int | None = 1) -> Path:
        """Atomically write ``obj`` as JSON to ``out/name``."""
        return atomic_write_json(self.path(name), obj, indent)

    def write_npz(self, name: str, arrays: dict[str, Any], compressed: bool = True) -> Path:
        """Atomically write ``arrays`` to ``out/name`` (``.npz``)."""
        return atomic_write_npz(self.path(name), arrays, compressed)

    def read_npz(self, name: str, required: Iterable[str] = ()) -> dict | None:
        """The arrays of ``out/name``, or ``None`` (missing; corrupt: warned, set aside)."""
        return read_npz(self.out / name, required)

    def read_json(self, name: str, required: Iterable[str] = (),
                  check: Callable[[dict], bool] | None = None) -> dict | None:
        """The JSON object of ``out/name``, or ``None`` (missing; corrupt: warned, set aside)."""
        return read_json(self.out / name, required, check)

    def read_csv(self, name: str, fields: Iterable[str],
                 check: Callable[[list[dict]], bool] | None = None) -> list[dict] | None:
        """The rows of ``out/name``, or ``None`` (missing; corrupt: warned, set aside)."""
        return read_csv(self.out / name, fields, check)

    def write_csv(self, name: str, fields: Iterable[str], rows: Iterable[dict]) -> Path:
        """Atomically write ``rows`` (dicts; keys beyond ``fields`` ignored) to ``out/name``."""
        return atomic_write_text(self.path(name), csv_text(fields, rows))

    def savefig(self, name: str, fig: Any, **kwargs: Any) -> Path:
        """Atomically save a matplotlib figure to ``out/name`` (see :func:`atomic_savefig`)."""
        return atomic_savefig(fig, self.path(name), **kwargs)

    def records(self, name: str, key: Callable[[dict], Any], required: Iterable[str] = (),
                check: Callable[[dict], bool] | None = None) -> Records:
        """The JSONL records of ``out/name`` (bad lines warned and dropped), to extend."""
        rec = Records(self.path(name), key, required, check)
        self._records.append(rec)
        return rec

    def write_results_csv(self, rows: Iterable[tuple[Any, str, float]],
                          name: str = "results.csv") -> Path:
        """Write the tidy ``out/results.csv`` (see :func:`write_results_csv`)."""
        return write_results_csv(self.path(name), self.study, rows)


def write_results_csv(path: Path, study: str, rows: Iterable[tuple[Any, str, float]]) -> Path:
    """Atomically write a tidy CSV: ``study, unit, metric, value``, one row per number.

    Non-finite values are written as ``nan``/``inf`` (``pandas.read_csv`` parses them).
    """
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["study", "unit", "metric", "value"])
    for unit, metric, value in rows:
        v = float(value)
        w.writerow([study, unit, metric, repr(v) if math.isfinite(v) else str(v)])
    return atomic_write_text(Path(path), buf.getvalue())


__all__ = ["Store", "Records", "StudyError", "StoreError", "CorruptRecordWarning",
           "precision", "atomic_write_bytes", "atomic_write_text", "atomic_write_json",
           "atomic_write_npz", "atomic_savefig", "read_npz", "read_json", "read_jsonl",
           "read_csv", "csv_text", "flatten_metrics",
           "tidy_rows", "write_results_csv", "MEASURED", "PROSE", "is_measured", "canonical",
           "config_diff"]
