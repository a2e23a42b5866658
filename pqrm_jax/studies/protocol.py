"""One protocol for every study: common flags, validated numbers, presets, claims, one driver.

A study module that follows it defines

* ``NAME``, ``HELP``;
* ``Config`` — a frozen dataclass of every result-changing setting (fields may be the
  library's Params), with ``to_json()`` (a plain one derives from :class:`StudyConfig`,
  whose ``to_json`` is :func:`config_json`);
* ``PRESETS`` — ``{"tiny": {...}, "reduced": {...}, "full": {}}``: field overrides of
  ``Config()`` chosen with ``--tiny`` / ``--reduced`` (``full`` is the default);
* ``configure(argv, overrides=None) -> (Config, argparse.Namespace)`` — its parser is
  :func:`parser` (the common flags below) plus the study's own, every number validated by the
  types of this module before any work;
* ``run_study(cfg, out, *, quiet=False, cluster=None, fresh=False)`` — computes into the store
  in ``out`` (resumable unit by unit);
* ``report(out)`` — writes ``report.md`` from the stored results (``--report-only``);
* ``claims(out) -> list[Claim]`` — each published claim with the measured value, its
  interval and a verdict, rendered by :func:`claims_table` and summarised for sweeps by
  :func:`claims_summary`;
* ``main = protocol.main_for(module)``, and ``sweep_summary(out)`` (headline numbers +
  ``"claims"``; :func:`summary_for` builds it from ``claims``).

The common flags (:func:`parser`), the same meaning in every study:

===================  ==============================================================
``--out DIR``        the study directory (default ``out/NAME``)
``--fresh``          delete this study's stored results in ``--out`` first
``--report-only``    write ``report.md`` from the stored results, compute nothing
``--seed N``         the root seed
``--no-progress``    no progress bars (deprecated alias: ``--quiet``)
``--tiny``           the smallest preset (seconds; for tests)
``--reduced``        a reduced preset (minutes)
``--chunk N``        work items per compiled call (studies that chunk; ``0`` = automatic)
``--coordinator``    … and ``--processes``, ``--process-id``, ``--init-timeout``
===================  ==============================================================

>>> p = parser("demo", "a demo study", seed=3)
>>> a = p.parse_args(["--tiny", "--quiet"])
>>> (a.out, a.seed, a.preset, a.no_progress, a.fresh, a.report_only)
('out/demo', 3, 'tiny', True, False, False)
>>> positive_int("3"), finite_float("-1e30"), fraction("0.5")
(3, -1e+30, 0.5)
>>> c = Claim("lab error < 3 %", "< 3 %", 0.021, (0.0, 0.03), "match")
>>> d = Claim("distance < 1 below σ_N = 1", "< 1", "max 1.2", "all < 1", "mismatch")
>>> print("\\n".join(claims_table([c, d])))
| claim | published | measured | interval | verdict |
|---|---|---|---|---|
| lab error < 3 % | < 3 % | 0.021 | [0, 0.03] | match |
| distance < 1 below σ_N = 1 | < 1 | max 1.2 | all < 1 | mismatch |
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

__all__ = ["Claim", "MATCH", "MISMATCH", "NOT_CHECKED", "PRESET_NAMES", "StudyConfig",
           "add_fresh",
           "apply_preset", "fresh_start",
           "check_argv_finite", "claims_summary", "claims_table", "config_json",
           "default_out", "figure", "MIN_MEMORY_BYTES", "memory_bytes_arg",
           "finite_float", "fraction", "main_for", "nonneg_float",
           "nonneg_int", "parser", "positive_float", "positive_int", "summary_for",
           "verdict_in"]

MATCH, MISMATCH, NOT_CHECKED = "match", "mismatch", "not checked"
PRESET_NAMES = ("tiny", "reduced", "full")


# ------------------------------------------------------------------------------------------
# validated numbers (argparse types: a bad value is "argument --flag: ..." and exit code 2)
# ------------------------------------------------------------------------------------------


def _number(raw: str, kind: type, what: str, ok: Callable[[Any], bool]) -> Any:
    try:
        v = kind(raw)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"must be {what}, got {raw!r}") from None
    if isinstance(v, float) and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be {what} (finite), got {raw!r}")
    if not ok(v):
        raise argparse.ArgumentTypeError(f"must be {what}, got {raw!r}")
    return v


def positive_int(raw: str) -> int:
    """An integer ≥ 1 (argparse type)."""
    return _number(raw, int, "an integer ≥ 1", lambda v: v >= 1)


def nonneg_int(raw: str) -> int:
    """An integer ≥ 0 (argparse type)."""
    return _number(raw, int, "an integer ≥ 0", lambda v: v >= 0)


MIN_MEMORY_BYTES = 1 << 16
"""The smallest ``--memory-bytes`` accepted (64 KiB): below it no study program fits (the
smallest one, one 29 × 29 grid of hssh-plus's cellular stages, needs 22 KB, and a chunk may
use only :data:`~pqrm_jax.studies.chunking.FRACTION` of the budget), so a smaller value is a
typo, refused before any work."""


def memory_bytes_arg(raw: str) -> int:
    """``--memory-bytes`` (argparse type of the studies that size a chunk from it): an
    integer ≥ :data:`MIN_MEMORY_BYTES`."""
    v = positive_int(raw)
    if v < MIN_MEMORY_BYTES:
        raise argparse.ArgumentTypeError(f"must be at least {MIN_MEMORY_BYTES} bytes (64 KiB), "
                                         f"got {raw!r}")
    return v


def finite_float(raw: str) -> float:
    """A finite number (argparse type): NaN and ±inf are refused."""
    return _number(raw, float, "a finite number", lambda v: True)


def positive_float(raw: str) -> float:
    """A finite number > 0 (argparse type)."""
    return _number(raw, float, "a finite number > 0", lambda v: v > 0)


def nonneg_float(raw: str) -> float:
    """A finite number ≥ 0 (argparse type)."""
    return _number(raw, float, "a finite number ≥ 0", lambda v: v >= 0)


def fraction(raw: str) -> float:
    """A number in the open interval (0, 1) (argparse type)."""
    return _number(raw, float, "a number in (0, 1)", lambda v: 0 < v < 1)


def check_argv_finite(argv: Sequence[str]) -> None:
    """Refuse a NaN or infinite number given to any flag (``--eps nan``), naming the flag.

    The CLI calls it for every study before the study parses its arguments, so no study can
    run on a NaN setting (the config guard would store it).

    >>> check_argv_finite(["--eps", "0.5", "--name", "x"])
    >>> check_argv_finite(["--eps", "nan"])
    Traceback (most recent call last):
    ...
    ValueError: --eps: NaN and infinite numbers are not valid settings, got 'nan'
    """
    flag = None
    for tok in argv:
        if tok.startswith("--"):
            flag, _, val = tok.partition("=")
            if not val:
                continue
            tok = val
        try:
            v = float(tok)
        except ValueError:
            continue
        if not math.isfinite(v):
            raise ValueError(f"{flag or 'argument'}: NaN and infinite numbers are not valid "
                             f"settings, got {tok!r}")


# ------------------------------------------------------------------------------------------
# the common flags
# ------------------------------------------------------------------------------------------


def default_out(name: str) -> str:
    """The default study directory of every study: ``out/NAME``."""
    return f"out/{name}"


def parser(name: str, help: str, *, seed: int = 0, chunk: bool = False,
           presets: Iterable[str] = ("tiny", "reduced"), cluster: bool = True,
           description: str | None = None) -> argparse.ArgumentParser:
    """The study's parser with the common flags (module doc); add the study's own after."""
    p = argparse.ArgumentParser(prog=f"pqrm-jax study {name}", description=description or help,
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    g = p.add_argument_group("common to every study (docs/studies.md)")
    g.add_argument("--out", default=default_out(name), metavar="DIR",
                   help="the study directory (resumable store)")
    g.add_argument("--fresh", action="store_true",
                   help="delete this study's stored results in --out first")
    g.add_argument("--report-only", action="store_true",
                   help="write the report from the stored results; compute nothing")
    g.add_argument("--seed", type=nonneg_int, default=seed, help="root seed")
    g.add_argument("--no-progress", "--quiet", dest="no_progress", action="store_true",
                   help="no progress bars (--quiet: deprecated alias)")
    presets = tuple(presets)
    for pre in presets:
        g.add_argument(f"--{pre}", dest="preset", action="store_const", const=pre,
                       help=f"the {pre} preset")
    g.set_defaults(preset="full")
    if chunk:
        g.add_argument("--chunk", type=nonneg_int, default=0, metavar="N",
                       help="work items per compiled call (0: sized automatically)")
    if cluster:
        from . import distributed

        distributed.add_arguments(p)
    return p


def apply_preset(config_cls: type, presets: dict, preset: str, args: argparse.Namespace,
                 flags: dict[str, str], overrides: dict | None = None) -> Any:
    """``Config`` of a preset, then the flags the user gave, then ``overrides`` (a sweep cell).

    ``flags`` maps Config field → argparse dest of a study flag; a flag left at ``None`` keeps
    the preset's value.
    """
    cfg = config_cls(**presets.get(preset, {}))
    given = {f: getattr(args, d) for f, d in flags.items() if getattr(args, d, None) is not None}
    return dataclasses.replace(cfg, **given, **(overrides or {}))


def config_json(cfg: Any) -> dict:
    """The JSON form of a Config dataclass (tuples as lists, NamedTuples as dicts)."""
    def conv(v):
        if hasattr(v, "_asdict"):
            return {k: conv(x) for k, x in v._asdict().items()}
        if isinstance(v, (tuple, list)):
            return [conv(x) for x in v]
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        return v

    return {f.name: conv(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


class StudyConfig:
    """Base of a study's ``Config`` dataclass: ``to_json()`` is :func:`config_json` (one
    definition instead of a delegate in every study).

    >>> @dataclasses.dataclass(frozen=True)
    ... class Config(StudyConfig):
    ...     runs: int = 2
    ...     ns: tuple[int, ...] = (6, 9)
    >>> Config().to_json()
    {'runs': 2, 'ns': [6, 9]}
    """

    def to_json(self) -> dict:
        """The JSON form stored in ``config.json`` (:func:`config_json`)."""
        return config_json(self)

    @classmethod
    def stored(cls, out: str | Path, name: str):
        """The config stored in ``out/config.json`` by a run of study ``name``: its fields of
        this class (lists back to tuples; other stored keys, e.g. prose, are ignored).

        Raises:
            StudyError: when ``out`` holds no readable ``config.json``.
        """
        import json

        from .store import StudyError

        try:
            d = json.loads((Path(out) / "config.json").read_text())
        except (OSError, ValueError) as exc:
            raise StudyError(f"{out} holds no {name} study (config.json: {exc}); run the "
                             "study first") from None
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()
                      if k in names})


def fresh_start(args: argparse.Namespace, out: str | Path, name: str, cluster=None, *,
                legacy: tuple[str, ...] = ()) -> None:
    """``--fresh`` in a study that opens its store itself: process 0 deletes this study's
    stored results in ``out`` (a directory of another study is refused) before any process
    reads it. Call it after the cluster is initialised, before the store is opened."""
    if not getattr(args, "fresh", False) or (cluster is not None and not cluster.is_main):
        return
    from .store import Store

    Store.wipe(out, name, legacy=legacy)


def add_fresh(p: argparse.ArgumentParser) -> None:
    """The common ``--fresh`` flag (for a study with its own parser; see :func:`fresh_start`)."""
    p.add_argument("--fresh", action="store_true",
                   help="delete this study's stored results in --out first")


# ------------------------------------------------------------------------------------------
# claims
# ------------------------------------------------------------------------------------------


class Claim(NamedTuple):
    """A published claim and what the study measured.

    Attributes:
        name: the claim in a few words.
        published: the published value or statement (text).
        measured: the measured value (a number or text).
        interval: the interval the measured value must lie in to match (``(lo, hi)``), or
            the criterion in words when it is not an interval (``"all < 1"``); ``None``
            when the verdict is not a test of the measured value.
        verdict: ``"match"``, ``"mismatch"`` or ``"not checked"`` (may carry a note after a
            colon: ``"mismatch: only 2 of 5 seeds"``).
    """

    name: str
    published: str
    measured: Any
    interval: tuple[float, float] | str | None
    verdict: str


def verdict_in(value: float, lo: float, hi: float) -> str:
    """``"match"`` when ``lo <= value <= hi`` (NaN: ``"not checked"``), else ``"mismatch"``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return NOT_CHECKED
    return MATCH if lo <= value <= hi else MISMATCH


def _cell(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def claims_table(claims: Iterable[Claim]) -> list[str]:
    """The markdown table of claims (one line per claim), the same in every study report."""
    lines = ["| claim | published | measured | interval | verdict |", "|---|---|---|---|---|"]
    for c in claims:
        iv = ("–" if c.interval is None else c.interval if isinstance(c.interval, str)
              else f"[{_cell(c.interval[0])}, {_cell(c.interval[1])}]")
        lines.append(f"| {c.name} | {c.published} | {_cell(c.measured)} | {iv} | {c.verdict} |")
    return lines


def figure(path: str, caption: str) -> list[str]:
    """Markdown lines that embed a report figure with its caption, the same in every report.

    Args:
        path: the figure's file name, relative to the report.
        caption: one or two sentences saying what the figure shows (axes, marks, what to
            compare); must not be empty.

    Returns:
        ``["![caption](path)", "", "*caption*", ""]``: the caption is the image's alt text and is
        printed below it.

    Raises:
        ValueError: when ``caption`` is empty.

    Example:
        >>> figure("fig.png", "Error rate against noise.")
        ['![Error rate against noise.](fig.png)', '', '*Error rate against noise.*', '']
    """
    caption = " ".join(caption.split())
    if not caption:
        raise ValueError(f"figure: caption of {path!r} is empty")
    return [f"![{caption}]({path})", "", f"*{caption}*", ""]


def claims_summary(claims: Iterable[Claim]) -> dict[str, str]:
    """claim → verdict, the ``"claims"`` entry of a sweep summary."""
    return {c.name: c.verdict for c in claims}


def summary_for(module: ModuleType) -> Callable[[Path], dict]:
    """A ``sweep_summary(out)`` from the module's ``claims(out)``: each numeric measured
    value as a headline number, and the verdicts under ``"claims"``."""
    def sweep_summary(out: Path) -> dict:
        cs = module.claims(Path(out))
        head = {c.name: float(c.measured) for c in cs
                if isinstance(c.measured, (int, float)) and not isinstance(c.measured, bool)}
        return {**head, "claims": claims_summary(cs)}

    return sweep_summary


# ------------------------------------------------------------------------------------------
# the one driver
# ------------------------------------------------------------------------------------------


def main_for(module: ModuleType) -> Callable[[list[str]], int]:
    """The study's ``main``: ``configure``, then ``report`` (``--report-only``) or
    ``run_study`` + ``report``; exit 0 (a claim's mismatch is a result, not an error)."""
    def main(argv: list[str] | None = None) -> int:
        cfg, args = module.configure(list(argv or []))
        out = Path(args.out)
        if not args.report_only:
            from . import distributed

            cluster = distributed.initialize_from(args)
            module.run_study(cfg, out, quiet=args.no_progress, cluster=cluster,
                             fresh=args.fresh)
            if not cluster.is_main:
                return 0
        path = module.report(out)
        print(f"wrote {path}")
        return 0

    main.__doc__ = f"``pqrm-jax study {module.NAME}`` (see :mod:`pqrm_jax.studies.protocol`)."
    return main
