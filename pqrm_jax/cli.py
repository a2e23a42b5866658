"""The ``pqrm-jax`` command: operator tables and studies.

    pqrm-jax tables NAME --json PATH        export a calculus's exact tables as JSON
    pqrm-jax tables --rebuild [NAME ...]    regenerate cached tables (progress bar)
    pqrm-jax tables --plot DIR              table figures and a report (the main job's first part)
    pqrm-jax study NAME [args...]           run a study (``pqrm-jax study --list``)
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
        print(f"unknown study {name!r}; known: {', '.join(sorted(studies))}", file=sys.stderr)
        return 2
    return int(studies[name].main(rest) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = {"tables": _tables, "study": _study}
    if not argv or argv[0] not in commands:
        print(__doc__)
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    return commands[argv[0]](argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
