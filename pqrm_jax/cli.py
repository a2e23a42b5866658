"""The ``pqrm-jax`` command: operator tables and studies.

    pqrm-jax tables NAME --json PATH        export a calculus's exact tables as JSON
    pqrm-jax tables NAME --format F PATH    export as F: json (default format) or sparq
                                            (a SparQ def-calculus file, docs/tables.md §sparq)
    pqrm-jax tables --rebuild [NAME ...]    regenerate cached tables (progress bar)
    pqrm-jax tables --plot DIR              table figures and a report (the main job's first part)
    pqrm-jax study NAME [args...]           run a study (``pqrm-jax study --list``)
    pqrm-jax --version                      the installed version
    pqrm-jax study NAME --sweep KEY=V1,V2 [--sweep ...] [args...]
                                            one study per grid cell of Config fields, and a
                                            sensitivity report (docs/studies.md §sweeps)

A user error (a bad argument, an unusable ``--out``, a locked or foreign study directory, a
corrupt table cache, an unknown calculus, an unwritable path) prints one line
``pqrm-jax: error: ...`` on stderr and exits with code 2, without a traceback; set
``PQRM_JAX_TRACEBACK=1`` to see the traceback. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys


def _tables(argv: list[str]) -> int:
    from . import calculi
    from .tables import cli as tables_cli

    p = argparse.ArgumentParser(prog="pqrm-jax tables", description="exact operator tables")
    p.add_argument("names", nargs="*", help=f"calculi ({', '.join(calculi.names())})")
    p.add_argument("--json", metavar="PATH", help="write the tables of NAME as JSON")
    p.add_argument("--format", nargs=2, metavar=("FORMAT", "PATH"),
                   help="write the tables of NAME in FORMAT (json or sparq) to PATH")
    p.add_argument("--rebuild", action="store_true", help="regenerate the cached tables")
    p.add_argument("--plot", metavar="DIR", help="write region/table figures and report.md")
    args = p.parse_args(argv)
    return tables_cli.run(args)


def _study(argv: list[str]) -> int:
    from .studies import discover

    studies = discover()
    if not argv or argv[0] in ("--list", "-h", "--help"):
        print("studies:")
        for name, mod in sorted(studies.items()):
            print(f"  {name:16s} {getattr(mod, 'HELP', '')}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in studies:
        import difflib

        near = difflib.get_close_matches(name, list(studies), n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise SystemExit(f"unknown study {name!r}{hint} (known: {', '.join(sorted(studies))})")
    from .studies.protocol import check_argv_finite

    check_argv_finite(rest)  # no study runs on a NaN or infinite setting
    if any(a == "--sweep" or a.startswith("--sweep=") for a in rest):
        from .studies import sweep

        return sweep.main(studies[name], rest)
    return int(studies[name].main(rest) or 0)


def user_errors() -> tuple[type[BaseException], ...]:
    """The exception types the CLI reports as a one-line user error (exit code 2)."""
    from .studies.distributed import DistributedError
    from .studies.store import StudyError
    from .tables import CacheError

    return (StudyError, CacheError, DistributedError, OSError, ValueError, KeyError)


def _message(exc: BaseException) -> str:
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.strerror or exc}: {exc.filename}"
    return str(exc) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 for user errors, printed on one line)."""
    import warnings

    default_format = warnings.formatwarning

    def one_line(message, category, filename, lineno, line=None):
        # a record set aside for recomputation is news for the user, not a code location
        if category.__name__ == "CorruptRecordWarning":
            return f"pqrm-jax: warning: {message}\n"
        return default_format(message, category, filename, lineno, line)

    warnings.formatwarning = one_line
    if argv is None:  # the command itself (not a call from Python): warm starts
        from . import compile_cache

        compile_cache.enable()  # PQRM_JAX_COMPILE_CACHE=DIR or =off; docs/benchmarks.md
    try:
        return _dispatch(list(sys.argv[1:] if argv is None else argv))
    finally:
        warnings.formatwarning = default_format


def _dispatch(argv: list[str]) -> int:
    import os

    commands = {"tables": _tables, "study": _study}
    if argv and argv[0] == "--version":
        from . import __version__

        print(f"pqrm-jax {__version__}")
        return 0
    if not argv or argv[0] not in commands:
        print(__doc__)
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    ok = False
    try:
        rc = commands[argv[0]](argv[1:])
        ok = rc == 0
        return rc
    except SystemExit as exc:
        if isinstance(exc.code, str):  # SystemExit("message") from a command
            print(f"pqrm-jax: error: {exc.code}", file=sys.stderr)
            return 2
        raise
    except user_errors() as exc:
        if os.environ.get("PQRM_JAX_TRACEBACK"):
            raise
        msg = " ".join(_message(exc).split())
        print(f"pqrm-jax: error: {msg}", file=sys.stderr)
        return 2
    finally:
        dist = sys.modules.get("pqrm_jax.studies.distributed")
        if dist is not None:  # tell the other processes of a run how this one ended
            dist.finish(ok)

if __name__ == "__main__":
    raise SystemExit(main())
