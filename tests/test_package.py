"""A proper package: licence, citation, changelog, typing marker; the wheel works on its own.

The slow test builds a wheel from a clean checkout (``git archive HEAD``), installs it into a
fresh virtual environment (dependencies from pip's configured index and cache), and runs
``pqrm-jax tables`` and a tiny padgett-mc study from a directory outside the source tree.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_license_citation_changelog_and_typing_marker_exist():
    lic = (ROOT / "LICENSE").read_text()
    assert lic.startswith("MIT License")
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "MIT"
    assert "py.typed" in meta["tool"]["setuptools"]["package-data"]["pqrm_jax"]
    assert (ROOT / "pqrm_jax" / "py.typed").exists()
    cff = (ROOT / "CITATION.cff").read_text()
    assert "cff-version: 1.2.0" in cff and "license: MIT" in cff
    from pqrm_jax import __version__
    assert f"version: {__version__}" in cff and meta["project"]["version"] == __version__
    # the five source documents of README's references table, each once
    for title in ("Practical Qualitative Relational Mapping and Navigation for Robots",
                  "Qualitative Relational Mapping and Navigation for Planetary Rovers",
                  "Qualitative Relational Mapping and Navigation for Long-Term Robotic Operation",
                  "Belief Space Planning using Qualitative Spatial Relationships",
                  "Creating and Utilizing Symbolic Representations of Spatial Knowledge "
                  "using Mobile Robots"):
        assert cff.count(f'title: "{title}"') == 1, title
        assert title in (ROOT / "README.md").read_text().replace("*", "")
    assert len(re.findall(r"^  - type: ", cff, re.M)) == 5
    log = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{__version__}]" in log


@pytest.mark.slow
def test_wheel_from_clean_checkout_runs_outside_the_source_tree(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "HEAD"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q", "-w",
                    str(dist)], check=True)
    (wheel,) = dist.glob("pqrm_jax-*.whl")
    import zipfile
    names = zipfile.ZipFile(wheel).namelist()
    for table in ("edc", "dcc", "lr_full", "quadrant"):
        assert f"pqrm_jax/data/tables/{table}.json" in names
    assert "pqrm_jax/py.typed" in names
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(wheel)], check=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["PQRM_JAX_CACHE"] = str(tmp_path / "cache")
    where = subprocess.run([str(py), "-c", "import pqrm_jax; print(pqrm_jax.__file__)"],
                           cwd=work, env=env, check=True, capture_output=True, text=True)
    assert str(venv) in where.stdout and str(ROOT) not in where.stdout
    out = subprocess.run([str(venv / "bin" / "pqrm-jax"), "tables"], cwd=work, env=env,
                         check=True, capture_output=True, text=True).stdout
    for name in ("edc", "dcc", "lr_full"):
        assert name in out
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())
    subprocess.run([str(venv / "bin" / "pqrm-jax"), "study", "padgett-mc", "--runs", "2",
                    "--levels", "2", "--samples", "16", "--landmarks", "5", "--quiet",
                    "--out", str(work / "out")], cwd=work, env=env, check=True,
                   capture_output=True, text=True)
    assert (work / "out" / "report.md").stat().st_size > 0
