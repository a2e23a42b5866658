"""Sweeps over a study's open choices: one study per grid cell and a sensitivity report.

``pqrm-jax study NAME --sweep key=v1,v2 [--sweep key2=w1,w2 ...] [study flags] --out DIR``
runs the study once per cell of the grid (the Cartesian product of the ``--sweep`` axes),
each cell in its own sub-directory ``DIR/key=v1,key2=w1`` holding a normal study store
(:mod:`.store`: lock, config guard, atomic verified records, resume), and ends with
``DIR/sweep_report.md``, ``DIR/sweep.csv`` (one row per cell), ``DIR/results.csv`` and one
figure per headline metric (``DIR/sweep_<metric>.png``: the metric against every axis).

* **Keys** are the fields of the study's ``Config`` dataclass (e.g. ``num_landmarks``,
  ``max_range`` of padgett-mc), so a sweep can vary a choice the study's flags do not expose.
  A value is parsed by the type of the field's default: integers, finite floats, strings,
  booleans (``true``/``false``), and tuples with ``+`` between items
  (``representations=edc+lr``). A one-value axis is a fixed override.
* **Bad input** — no ``=``, an empty or repeated value, a repeated key, an unknown key (the
  known ones are listed), a value of the wrong type, a key that a study flag also sets —
  raises :class:`SweepError` (a ``ValueError``: one line ``pqrm-jax: error: ...``) before
  anything is computed; every cell's config is also checked by the study (``configure``)
  first.
* **Resume** — the sweep directory is itself a store (study ``NAME-sweep``) that guards the
  axes and the base configuration (a different sweep in the same ``--out`` is refused) and
  records each finished cell in ``cells.jsonl``; a re-run skips the recorded cells, and an
  unfinished cell resumes inside its own store.
* **Processes** — with ``--coordinator/--processes/--process-id`` (:mod:`.distributed`) every
  process walks the same cells in the same order and the study splits each cell's chunks
  over the processes (bit-identical to one process); process 0 alone writes.

A study supports sweeps when its module defines ``Config`` (a dataclass),
``configure(argv, overrides) -> (Config, argparse.Namespace)`` (the study's flags, including
``--out``, ``--fresh``, ``--quiet``, ``--report-only`` and the multi-process ones),
``run_study(cfg, out, *, quiet, cluster)``, ``main(argv)`` (with ``--report-only``: the cell's
own report) and ``sweep_summary(out) -> dict`` (headline numbers, strings, and ``"claims"``:
claim → verdict). The report lists, per published claim, the cells that reproduce it.

>>> import dataclasses
>>> @dataclasses.dataclass
... class Cfg:
...     n: int = 3
...     r: float = 1.0
...     reps: tuple[str, ...] = ("a", "b")
>>> axes = parse_axes(["n=3,5", "reps=a+b,a"], Cfg)
>>> [cell_name(c) for c in grid(axes)]
['n=3,reps=a+b', 'n=3,reps=a', 'n=5,reps=a+b', 'n=5,reps=a']
>>> parse_axes(["n=2.5"], Cfg)
Traceback (most recent call last):
...
pqrm_jax.studies.sweep.SweepError: --sweep n=2.5: n takes integers (its default is 3), got '2.5'
>>> parse_axes(["m=1"], Cfg)
Traceback (most recent call last):
...
pqrm_jax.studies.sweep.SweepError: --sweep m=1: unknown key 'm'; the keys are n, r, reps
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
import sys
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Axis", "SweepError", "parse_axes", "split_argv", "grid", "cell_name", "run",
           "main", "write_sweep_report", "PROTOCOL"]

#: What a study module must define to be swept.
PROTOCOL = ("Config", "configure", "run_study", "main", "sweep_summary", "NAME")

_SAFE = re.compile(r"^[A-Za-z0-9_.+\-]+$")  # a value as it appears in a cell directory name


class SweepError(ValueError):
    """A ``--sweep`` argument cannot be used (syntax, key, type); the CLI prints one line."""


class Axis(NamedTuple):
    """One ``--sweep key=v1,v2`` axis: the Config field and its parsed values."""

    key: str
    values: tuple


def split_argv(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(sweep specs, the other arguments)`` of a study command line.

    >>> split_argv(["--runs", "5", "--sweep", "n=1,2", "--sweep=r=0.5", "--quiet"])
    (['n=1,2', 'r=0.5'], ['--runs', '5', '--quiet'])
    """
    specs, rest = [], []
    it = iter(range(len(argv)))
    for i in it:
        a = argv[i]
        if a == "--sweep":
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                raise SweepError("--sweep needs a value KEY=V1,V2,...")
            specs.append(argv[i + 1])
            next(it)
        elif a.startswith("--sweep="):
            specs.append(a[len("--sweep="):])
        else:
            rest.append(a)
    return specs, rest


def _default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def _coerce(spec: str, key: str, raw: str, default: Any) -> Any:
    def bad(what: str) -> SweepError:
        return SweepError(f"--sweep {spec}: {key} takes {what} (its default is "
                          f"{_fmt(default)}), got {raw!r}")

    if isinstance(default, bool):
        low = raw.lower()
        if low not in ("true", "false", "1", "0", "yes", "no"):
            raise bad("true or false")
        return low in ("true", "1", "yes")
    if isinstance(default, int):
        if not re.fullmatch(r"[+-]?\d+", raw):
            raise bad("integers")
        return int(raw)
    if isinstance(default, float):
        try:
            v = float(raw)
        except ValueError:
            raise bad("numbers") from None
        if not math.isfinite(v):
            raise bad("finite numbers")
        return v
    if isinstance(default, str):
        return raw
    if isinstance(default, (tuple, list)) and default:
        items = raw.split("+")
        if any(not x for x in items):
            raise bad("items joined by '+'")
        return tuple(_coerce(spec, key, x, default[0]) for x in items)
    raise SweepError(f"--sweep {spec}: {key} (default {default!r}) is not a sweepable "
                     "type (integers, numbers, strings, booleans, tuples)")


def _fmt(v: Any) -> str:
    if isinstance(v, (tuple, list)):
        return "+".join(_fmt(x) for x in v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(v) if isinstance(v, float) else str(v)


def parse_axes(specs: list[str], config_cls: type) -> list[Axis]:
    """The axes of ``--sweep`` specs against the fields of ``config_cls`` (a dataclass).

    Raises:
        SweepError: bad syntax, an unknown or repeated key, an empty or repeated value, a
            value of the wrong type (parsed by the type of the field's default).
    """
    fields = {f.name: f for f in dataclasses.fields(config_cls)}
    axes: list[Axis] = []
    for spec in specs:
        key, eq, raw = spec.partition("=")
        key = key.strip()
        if not eq or not key:
            raise SweepError(f"--sweep {spec!r}: expected KEY=V1,V2,... (e.g. "
                             f"--sweep {next(iter(fields))}=...)")
        if key not in fields:
            raise SweepError(f"--sweep {spec}: unknown key {key!r}; the keys are "
                             f"{', '.join(fields)}")
        if any(a.key == key for a in axes):
            raise SweepError(f"--sweep {spec}: {key} is swept twice; give all its values "
                             "in one --sweep")
        items = raw.split(",")
        if any(not x.strip() for x in items):
            raise SweepError(f"--sweep {spec}: empty value (values are separated by ',')")
        default = _default(fields[key])
        values = tuple(_coerce(spec, key, x.strip(), default) for x in items)
        if len(set(values)) != len(values):
            raise SweepError(f"--sweep {spec}: a value is given twice")
        for v in values:
            if not _SAFE.match(_fmt(v)):
                raise SweepError(f"--sweep {spec}: value {_fmt(v)!r} cannot name a cell "
                                 "directory (letters, digits and _ . + - only)")
        axes.append(Axis(key, values))
    if not axes:
        raise SweepError("no --sweep axis given")
    return axes


def grid(axes: list[Axis]) -> list[dict]:
    """The cells (``{key: value}``) of the axes' Cartesian product, first axis slowest."""
    return [dict(zip([a.key for a in axes], vals, strict=True))
            for vals in itertools.product(*[a.values for a in axes])]


def cell_name(cell: dict) -> str:
    """The sub-directory name of a cell: ``key=value`` joined by ``,``."""
    return ",".join(f"{k}={_fmt(v)}" for k, v in cell.items())


def _jsonable(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v


def _check_protocol(module: ModuleType) -> None:
    missing = [n for n in PROTOCOL if not hasattr(module, n)]
    if missing:
        name = getattr(module, "NAME", module.__name__)
        raise SweepError(f"study {name} does not support --sweep (its module lacks "
                         f"{', '.join(missing)}; see pqrm_jax.studies.sweep)")


def main(module: ModuleType, argv: list[str]) -> int:
    """``pqrm-jax study NAME --sweep ...``: run (or resume) the sweep, write its report."""
    path = run(module, argv)
    if path is not None:
        print(f"sweep report: {path}")
    return 0


def run(module: ModuleType, argv: list[str]) -> Path | None:
    """Run or resume the sweep of ``module`` given its command line; the report path.

    Returns None on processes other than 0 of a multi-process run (they write nothing).
    """
    from . import distributed
    from .store import Store

    _check_protocol(module)
    specs, rest = split_argv(argv)
    axes = parse_axes(specs, module.Config)
    base, args = module.configure(rest)
    presets = getattr(module, "PRESETS", {})
    plain = module.Config(**presets.get(getattr(args, "preset", "full"), {}))
    for a in axes:
        if getattr(base, a.key) != getattr(plain, a.key):
            raise SweepError(f"--sweep {a.key}=...: {a.key} is also set by another flag (to "
                             f"{_fmt(getattr(base, a.key))}); set it or sweep it, not both")
    cells = grid(axes)
    cfgs = [_configure_cell(module, rest, c) for c in cells]  # every cell checked first
    out = Path(args.out)
    sweep_study = f"{module.NAME}-sweep"
    swept = {a.key for a in axes}
    fields = {f.name for f in dataclasses.fields(module.Config)}
    guard = {"study": module.NAME,
             "axes": {a.key: [_jsonable(v) for v in a.values] for a in axes},
             "base": {k: v for k, v in _to_json(base).items()
                      if k in fields and k not in swept}}
    if getattr(args, "report_only", False):
        with Store.open(out, sweep_study, None) as st:
            if st.config.get("axes") != guard["axes"]:
                raise SweepError(f"{out} holds a sweep over {st.config.get('axes')}, not "
                                 f"{guard['axes']}; give its --sweep axes with --report-only")
            return write_sweep_report(st, module.NAME, axes, _records(st).values())
    cluster = distributed.initialize_from(args)  # before any JAX computation
    distributed.agree(cluster, guard, f"{module.NAME} sweep")
    st = log = None

    def prepare():  # process 0 only: open the sweep store, list the cells left
        nonlocal st, log
        st = Store.open(out, sweep_study, guard, fresh=getattr(args, "fresh", False),
                        advice="use another --out or --fresh")
        log = _records(st)
        return [cell_name(c) not in log for c in cells]

    quiet = getattr(args, "quiet", False) or getattr(args, "no_progress", False)
    try:
        left = distributed.decide(cluster, len(cells), prepare)
        todo = [i for i in range(len(cells)) if left[i]]
        if cluster.is_main and not quiet:
            print(f"{sweep_study}: {len(cells)} cells, {len(cells) - len(todo)} already done",
                  file=sys.stderr)
        for n, i in enumerate(todo):
            name = cell_name(cells[i])
            if cluster.is_main and not quiet:
                print(f"{sweep_study}: cell {n + 1}/{len(todo)}: {name}", file=sys.stderr)
            module.run_study(cfgs[i], out / name, quiet=quiet, cluster=cluster)
            if cluster.is_main:
                module.main(["--report-only", "--out", str(out / name)])
                log.add({"cell": name,
                         "values": {k: _jsonable(v) for k, v in cells[i].items()},
                         "summary": module.sweep_summary(out / name)})
        if not cluster.is_main:
            return None
        return write_sweep_report(st, module.NAME, axes, log.values())
    finally:
        if st is not None:
            st.close()


def _to_json(cfg) -> dict:
    if hasattr(cfg, "to_json"):
        return cfg.to_json()
    from .protocol import config_json

    return config_json(cfg)


def _configure_cell(module: ModuleType, rest: list[str], cell: dict):
    """The study's config of one cell; its refusal (an argparse error) as a SweepError."""
    import contextlib
    import io

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return module.configure(rest, overrides=cell)[0]
    except SystemExit as exc:
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        why = lines[-1].split("error: ", 1)[-1] if lines else f"exit code {exc.code}"
        raise SweepError(f"--sweep cell {cell_name(cell)}: {why}") from None


def _records(st):
    return st.records("cells.jsonl", key=lambda r: r["cell"],
                      required=("cell", "values", "summary"),
                      check=lambda r: isinstance(r["values"], dict)
                      and isinstance(r["summary"], dict))


# ------------------------------------------------------------------------------------------
# the sensitivity report
# ------------------------------------------------------------------------------------------


def _numeric(summary: dict) -> dict[str, float]:
    return {k: float(v) for k, v in summary.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)}


def _cell_value(rec: dict, key: str) -> Any:
    v = rec["values"][key]
    return tuple(v) if isinstance(v, list) else v


def sensitivity(axes: list[Axis], records: list[dict]) -> dict[str, dict[str, float]]:
    """metric → axis → spread of the metric's mean over that axis's values.

    For each value of the axis the metric is averaged over the other axes' cells; the spread
    is max − min of those means (NaN cells left out). A large spread means the choice moves
    the metric.
    """
    metrics = sorted({m for r in records for m in _numeric(r["summary"])})
    out: dict[str, dict[str, float]] = {}
    for m in metrics:
        out[m] = {}
        for a in axes:
            means = []
            for v in a.values:
                xs = [_numeric(r["summary"]).get(m, math.nan) for r in records
                      if _cell_value(r, a.key) == v]
                xs = [x for x in xs if math.isfinite(x)]
                if xs:
                    means.append(float(np.mean(xs)))
            out[m][a.key] = (max(means) - min(means)) if len(means) > 1 else math.nan
    return out


def _figures(st, axes: list[Axis], records: list[dict]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = sorted({m for r in records for m in _numeric(r["summary"])})
    multi = [a for a in axes if len(a.values) > 1]
    names = []
    if not multi:
        return names
    for m in metrics:
        fig, axs = plt.subplots(1, len(multi), figsize=(4.2 * len(multi), 3.4), squeeze=False)
        for ax, a in zip(axs[0], multi, strict=True):
            others = [b for b in multi if b.key != a.key]
            groups: dict[tuple, list] = {}
            for r in records:
                g = tuple(_cell_value(r, b.key) for b in others)
                groups.setdefault(g, []).append(r)
            labels = [_fmt(v) for v in a.values]
            try:
                ordered = sorted(groups.items(), key=lambda t: t[0])
            except TypeError:  # values of mixed types: by their text
                ordered = sorted(groups.items(), key=lambda t: str(t[0]))
            for gi, (g, rs) in enumerate(ordered):
                ys = []
                for v in a.values:
                    hit = [_numeric(r["summary"]).get(m, math.nan) for r in rs
                           if _cell_value(r, a.key) == v]
                    ys.append(hit[0] if hit else math.nan)
                lab = ", ".join(f"{b.key}={_fmt(x)}" for b, x in zip(others, g, strict=True))
                # equal curves stay visible: hollow markers shrinking with the group
                # index (concentric where points coincide) and a dash pattern per group
                ax.plot(range(len(labels)), ys, marker="osD^v<>p"[gi % 8], mfc="none",
                        ms=3 + 2 * max(min(len(groups), 6) - 1 - gi, 0),
                        ls=("-", "--", ":", "-.")[gi % 4], lw=1, alpha=0.8,
                        label=lab if len(groups) <= 8 else None)
            ax.set_xticks(range(len(labels)), labels, rotation=30 if len(labels) > 4 else 0)
            ax.set_xlabel(a.key)
            ax.set_ylabel(m)
            if 1 < len(groups) <= 8:
                ax.legend(fontsize=6)
        fig.suptitle(m, fontsize=9)
        fig.tight_layout()
        fname = f"sweep_{re.sub(r'[^A-Za-z0-9_.+-]', '_', m)}.png"
        st.savefig(fname, fig, dpi=90)
        plt.close(fig)
        names.append(fname)
    return names


def write_sweep_report(st, study: str, axes: list[Axis], records: list[dict]) -> Path:
    """``sweep_report.md``, ``sweep.csv``, ``results.csv`` and the figures of a sweep store."""
    from .store import tidy_rows

    order = {cell_name(c): i for i, c in enumerate(grid(axes))}
    records = sorted([r for r in records if r["cell"] in order], key=lambda r: order[r["cell"]])
    metrics = sorted({m for r in records for m in _numeric(r["summary"])})
    texts = sorted({k for r in records for k, v in r["summary"].items()
                    if isinstance(v, str)})
    rows = []
    for r in records:
        row = {a.key: _fmt(_cell_value(r, a.key)) for a in axes}
        row.update({m: r["summary"].get(m, "") for m in metrics + texts})
        row["claims_matched"] = sum(str(v).startswith("match")
                                    for v in r["summary"].get("claims", {}).values())
        rows.append(row)
    fields = [a.key for a in axes] + metrics + texts + ["claims_matched"]
    st.write_csv("sweep.csv", fields, rows)
    st.write_results_csv(tidy_rows([{"cell": r["cell"], **r["summary"]} for r in records],
                                   unit=lambda r: r["cell"], skip=("cell",)))
    figs = _figures(st, axes, records)
    n_cells = math.prod(len(a.values) for a in axes)
    lines = [f"# {study} sweep: sensitivity report", "",
             f"{len(records)} of {n_cells} cells finished. Axes (Config fields):", ""]
    lines += [f"- `{a.key}` = {', '.join(_fmt(v) for v in a.values)}" for a in axes]
    lines += ["", "Each cell is a full study in its own sub-directory (its own `report.md`); "
              "`sweep.csv` has one row per cell.", "", "## Cells", ""]
    head = [a.key for a in axes] + metrics + texts
    lines.append("| " + " | ".join(head) + " | claims matched |")
    lines.append("|" + "---|" * (len(head) + 1))
    for row in rows:
        cells = [row[a.key] for a in axes]
        cells += [f"{row[m]:.4g}" if isinstance(row[m], (int, float)) else str(row[m])
                  for m in metrics]
        cells += [str(row[t]) for t in texts]
        lines.append("| " + " | ".join(cells) + f" | {row['claims_matched']} |")
    sens = sensitivity(axes, records)
    multi = [a for a in axes if len(a.values) > 1]
    if multi and metrics:
        lines += ["", "## Sensitivity", "",
                  "Spread (max − min) of each metric's mean over the values of one axis, the "
                  "other axes averaged:", ""]
        lines.append("| metric | " + " | ".join(a.key for a in multi) + " |")
        lines.append("|---|" + "---|" * len(multi))
        for m in metrics:
            lines.append(f"| {m} | " + " | ".join(f"{sens[m][a.key]:.4g}" for a in multi)
                         + " |")
    claims = sorted({c for r in records for c in r["summary"].get("claims", {})})
    if claims:
        lines += ["", "## Published claims: which cells reproduce them", ""]
        lines.append("| claim | cells matching | matching cells |")
        lines.append("|---|---|---|")
        for c in claims:
            ok = [r["cell"] for r in records
                  if str(r["summary"].get("claims", {}).get(c, "")).startswith("match")]
            shown = ", ".join(f"`{x}`" for x in ok[:12]) + (" …" if len(ok) > 12 else "")
            lines.append(f"| {c} | {len(ok)}/{len(records)} | {shown or 'none'} |")
    if figs:
        from .protocol import figure

        lines += ["", "## Figures", ""]
        for m, f in zip(metrics, figs, strict=True):  # one figure per metric, same order
            lines += figure(f, f"`{m}` of every finished cell (y) against each swept axis "
                            "(x, one panel per axis with more than one value); one line per "
                            "combination of the other axes' values, named in the legend when "
                            "there are at most 8.")
    return st.write_text("sweep_report.md", "\n".join(lines) + "\n")
