"""The repository documents itself: docs citations resolve, nothing points outside the repo.

Code, tests, notebooks and the docs cite design notes as ``docs/<page>.md §<id>`` (see
docs/README.md); a citation must name an existing page and, when it has a ``§<id>``, a
heading of that page that starts with ``§<id>``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SCANNED = ("pqrm_jax", "tests", "benchmarks", "scripts", "notebooks", "sim", "docs")
SUFFIXES = {".py", ".md", ".ipynb", ".sh", ".toml", ".txt", ".cfg", ".json"}
SKIP_PARTS = {".venv", "__pycache__", "data", "results", ".ipynb_checkpoints"}

# "docs/decisions.md §2.1", "docs/pqrm.md §measurement", "docs/decisions.md §2.1–2.2"
CITATION = re.compile(r"docs/([A-Za-z0-9_\-]+\.md)(?:[ \t]+§[ ]?([\w.\-]+(?:–[\w.\-]+)?))?")
# inside docs pages: "[studies.md](studies.md) §padgett-mc"
LINK_CITATION = re.compile(r"\]\(([A-Za-z0-9_\-]+\.md)\)[ \t]+§([\w.\-]+)")
HEADING = re.compile(r"^#+\s+§([\w.\-]+)", re.M)
# built from parts so that this file does not match its own check
FORBIDDEN = ("SPEC" + " §", ".." + "/shared")


def _files(parts=SCANNED, readme=True):
    out = []
    for top in parts:
        base = ROOT / top
        if not base.exists():
            continue
        for p in base.rglob("*"):
            skipped = SKIP_PARTS & set(p.relative_to(ROOT).parts)
            if p.is_file() and p.suffix in SUFFIXES and not skipped:
                out.append(p)
    if readme:
        out.append(ROOT / "README.md")
    return sorted(out)


def _anchors(page: str) -> set[str]:
    return set(HEADING.findall((DOCS / page).read_text(encoding="utf-8")))


def _ids(raw: str) -> list[str]:
    """Section ids of one citation, without trailing punctuation; a range gives both ends."""
    ids = []
    for part in raw.split("–"):
        part = part.rstrip(".-")
        if part:
            ids.append(part)
    return ids


def _citations():
    found = []
    for path in _files():
        text = path.read_text(encoding="utf-8")
        rel = path.relative_to(ROOT).as_posix()
        for m in CITATION.finditer(text):
            found.append((rel, m.group(1), m.group(2)))
        if path.parent == DOCS:
            for m in LINK_CITATION.finditer(text):
                found.append((rel, m.group(1), m.group(2)))
    return found


def test_ids_and_ranges():
    assert _ids("2.1–2.2") == ["2.1", "2.2"]
    assert _ids("2.3.") == ["2.3"]
    assert _ids("padgett-mc") == ["padgett-mc"]
    m = CITATION.search("see docs/decisions.md §2.1–2.2, and more")
    assert m is not None and m.groups() == ("decisions.md", "2.1–2.2")


def test_the_code_cites_the_docs():
    cites = _citations()
    from_code = [c for c in cites if c[0].startswith("pqrm_jax/")]
    assert len(from_code) >= 30, "the package should cite its design notes"


def test_every_docs_citation_resolves():
    bad = []
    anchors: dict[str, set[str]] = {}
    for where, page, raw in _citations():
        if not (DOCS / page).is_file():
            bad.append(f"{where}: docs/{page} does not exist")
            continue
        if raw is None:
            continue
        have = anchors.setdefault(page, _anchors(page))
        for sid in _ids(raw):
            if sid not in have:
                bad.append(f"{where}: docs/{page} has no heading §{sid}")
    assert not bad, "\n".join(sorted(set(bad)))


def test_decisions_keep_the_numbered_sections():
    have = _anchors("decisions.md")
    for sid in [str(i) for i in range(1, 13)] + ["2.1", "2.2", "2.3"]:
        assert sid in have, f"decisions.md lost its §{sid} heading"


def test_references_name_every_citation_key():
    text = (DOCS / "references.md").read_text(encoding="utf-8")
    for key, word in [("P", "Padgett"), ("M", "McClelland"), ("MT", "McClelland"),
                      ("Z", "Zilberman"), ("B", "Beeson")]:
        assert re.search(rf"^\| \*\*{key}\*\* \|[^\n]*{word}", text, re.M), key


@pytest.mark.parametrize("needle", FORBIDDEN)
def test_nothing_points_outside_the_repository(needle):
    hits = []
    for path in _files(("pqrm_jax", "tests", "benchmarks", "scripts", "notebooks", "sim")):
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if needle in line:
                hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()[:80]}")
    assert not hits, "\n".join(hits)


# Citations of the source digests (notes outside the repository): "the d-", "d- §3.6",
# "d- decisions", "d-s/…" (d- = the word, spelt out only in the test strings below).
# hashlib's hexdigest()/digest() never match (no word boundary, or no following §/"the").
_D = "dig" + "est"
DIGEST_CITATION = re.compile(
    rf"\bthe\s+{_D}\b|\b{_D}\s*§|\b{_D}s?/|\b{_D}\s+decisions?\b|\bof\s+the\s+{_D}\b", re.I)


def test_digest_pattern():
    assert DIGEST_CITATION.search("decision §3.7 of the " + _D + ": existence")
    assert DIGEST_CITATION.search("(Z §4.3; " + _D + " decisions §3.5–3.6)")
    assert DIGEST_CITATION.search("knob, " + _D.capitalize() + " §7.3")
    assert not DIGEST_CITATION.search("return h.hex" + _D + "()[:16]")
    assert not DIGEST_CITATION.search("hashlib.sha256(b).hex" + _D + "()")


def test_nothing_cites_the_digest():
    """Code, tests, benchmarks, scripts, notebooks and the README cite docs/, not the notes."""
    hits = []
    for path in _files(("pqrm_jax", "tests", "benchmarks", "scripts", "notebooks", "sim")):
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if DIGEST_CITATION.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()[:80]}")
    assert not hits, "\n".join(hits)


def test_bsp_decisions_are_documented():
    """Every decision key the qbsp study writes to config.json has a heading in docs/bsp.md."""
    from pqrm_jax.studies import qbsp

    have = _anchors("bsp.md")
    named = {"compositions": "compositions-once", "observability": "observability",
             "target": "target", "link_rule": "link-rule"}
    missing = [k for k in qbsp.DECISIONS if named.get(k, k) not in have]
    assert not missing, f"docs/bsp.md has no heading for decisions {missing}"
    for sid in ("calibration", "results", "gaps", "parameters", "plan-exists"):
        assert sid in have, sid


def test_qlink_decisions_are_documented():
    """The β choice, the calibration, every decision the code cites and the status are there."""
    have = _anchors("qlink.md")
    for sid in ("Q1", "Q12", "Q20", "start", "calibration", "parameters", "results", "gaps"):
        assert sid in have, sid
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    studies = _anchors("studies.md")
    for page in ("bsp.md", "qlink.md", "hssh.md"):
        assert f"]({page})" in index, f"docs/README.md does not index {page}"
    for sid in ("qbsp", "qlink", "hssh-plus", "hssh-localization"):
        assert sid in studies, f"docs/studies.md has no §{sid}"
