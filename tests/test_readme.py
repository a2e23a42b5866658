"""The README's quick start runs: every ```pycon block is a doctest, run from the repository
root (where tests/data holds its example files), in one shared namespace, in order."""

from __future__ import annotations

import doctest
import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_readme_quick_start_runs(monkeypatch):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```pycon\n(.*?)```", text, re.S)
    assert len(blocks) >= 8, "the quick start should have a block per system"
    monkeypatch.chdir(ROOT)
    parser = doctest.DocTestParser()
    globs: dict = {}
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for i, block in enumerate(blocks):
        test = parser.get_doctest(block, globs, f"README block {i}", "README.md", 0)
        runner.run(test, clear_globs=False)
        globs = test.globs
    res = runner.summarize(verbose=False)
    assert res.failed == 0 and res.attempted > 30, res
    assert os.getcwd() == str(ROOT)
