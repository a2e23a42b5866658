"""``pqrm-jax tables``: export, rebuild and plot the operator tables."""

from __future__ import annotations

import json
import time
from pathlib import Path

from .. import calculi
from .store import load_tables

PUBLISHED_COMPOSE = {("1", "5"): {"1", "5", "11", "12", "17", "19"},
                     ("5", "5"): {"12", "17", "18", "19", "20"},
                     ("11", "5"): {"17", "18", "19", "20"}}


def _names(args) -> list[str]:
    names = args.names or list(calculi.names())
    for n in names:
        calculi.get(n)  # raises with the list of known names
    return names


FORMATS = ("json", "sparq")


def export(name: str, fmt: str, path: str) -> None:
    """Write the tables of calculus ``name`` to ``path`` in ``fmt`` (one of :data:`FORMATS`)."""
    if fmt not in FORMATS:
        raise SystemExit(f"unknown table format {fmt!r}; known formats: {', '.join(FORMATS)}")
    t = load_tables(calculi.get(name))
    if fmt == "sparq":
        from .sparq import write_sparq

        write_sparq(t, path)
    else:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(t.to_json(), indent=1))
    print(f"wrote {path} ({fmt}): {t.summary()}")


def run(args) -> int:
    fmt = getattr(args, "format", None)
    if args.json and fmt:
        raise SystemExit("give either --json PATH or --format FORMAT PATH, not both")
    export_to = ("json", args.json) if args.json else tuple(fmt) if fmt else None
    if export_to:
        if len(args.names) != 1:
            raise SystemExit(f"--{'json' if args.json else 'format'} needs exactly one "
                             "calculus name")
        export(args.names[0], *export_to)
    if args.rebuild:
        for name in _names(args):
            t0 = time.perf_counter()
            t = load_tables(calculi.get(name), rebuild=True, progress=True)
            print(f"{name}: {t.summary()} ({time.perf_counter() - t0:.1f} s)")
    if args.plot:
        plot_report(Path(args.plot), _names(args))
    if not (export_to or args.rebuild or args.plot):
        for name in _names(args):
            print(load_tables(calculi.get(name)).summary())
    return 0


def plot_report(out: Path, names: list[str]) -> Path:
    """Region figures, the EDC composition-size map and a report.md with table sizes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plots import plot_compose_sizes, plot_regions

    out.mkdir(parents=True, exist_ok=True)
    n = len(names)
    cols = min(3, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.2 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        plot_regions(calculi.get(name), ax)
    for ax in axes.flat[n:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "regions.png", dpi=110)
    plt.close(fig)
    edc = load_tables(calculi.get("edc"))
    fig, ax = plt.subplots(figsize=(6, 5))
    plot_compose_sizes(edc, ax)
    fig.tight_layout()
    fig.savefig(out / "edc_compose_sizes.png", dpi=110)
    plt.close(fig)
    cap = ("Relations AB:C of each calculus with A = (0, 0), B = (0, 1): areas filled, line "
           "relations as thick lines, point relations (C = A, C = B) as markers; relations "
           "that need A = B cannot appear in this frame and are named in the title.")
    lines = ["# Operator tables", "", f"![{cap}](regions.png)", "", f"*{cap}*", "",
             "| calculus | states | compose entries | LEFT/RIGHT/INVERSE entries | adjacent pairs |"
             " undecided by B&B (all certified by z3) | open |", "|---|---|---|---|---|---|---|"]
    for name in names:
        s = load_tables(calculi.get(name)).summary()
        u = s["unary_entries"]
        lines.append(f"| {name} | {s['states']} | {s['compose_entries']} | {u['left']}/"
                     f"{u['right']}/{u['inverse']} | {s['adjacent_pairs']} | "
                     f"{s['undecided_by_bnb']} | {s['open']} |")
    lines += ["", "## Published EDC compositions (M§III.C)", "",
              "| entry | published | computed | match |", "|---|---|---|---|"]
    for (a, b), pub in PUBLISHED_COMPOSE.items():
        got = edc.compose_labels(a, b)
        lines.append(f"| COMPOSE({a},{b}) | {sorted(pub, key=int)} | {sorted(got, key=int)} | "
                     f"{'match' if got == pub else 'MISMATCH'} |")
    lines += ["", "![edc compose](edc_compose_sizes.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
