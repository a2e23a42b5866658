"""Every notebook in notebooks/ is executed top to bottom by the real kernel, and is stored
with its outputs (small) so that it renders without running (scripts/refresh_notebooks.py)."""

import base64
import re
import struct
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))
MAX_FILE_BYTES = 450_000      # one notebook file, sources + stored outputs
MAX_PNG_WIDTH = 700           # scripts/refresh_notebooks.py re-encodes wider images
# a cell that makes a figure: it must have stored an image
FIGURE = re.compile(r"plt\.(subplots|figure|bar|semilogy)\(|plot\.draw_|display\(Image\(|"
                    r"plot_regions\(|plot_compose_sizes\(")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors


def _png_width(data: str) -> int:
    raw = base64.b64decode(data)
    assert raw[:8] == b"\x89PNG\r\n\x1a\n", "stored image/png is not a PNG"
    return struct.unpack(">I", raw[16:20])[0]


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 10


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_with_small_outputs(path):
    """Outputs of one fresh top-to-bottom run are in the file: every code cell numbered 1, 2,
    … in order, no error, printed text where a cell prints, an image where a cell draws a
    figure; the file and its images stay small."""
    assert path.stat().st_size <= MAX_FILE_BYTES, f"{path.name}: {path.stat().st_size} bytes"
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code
    counts = [c.get("execution_count") for c in code]
    assert counts == list(range(1, len(code) + 1)), (
        f"{path.name}: execution counts {counts} — run scripts/refresh_notebooks.py {path.name}")
    images = 0
    for i, c in enumerate(code):
        outs = c.get("outputs", [])
        kinds = {o.get("output_type") for o in outs}
        assert "error" not in kinds, f"{path.name} code cell {i + 1} stored an error"
        pngs = [o["data"]["image/png"] for o in outs if "image/png" in o.get("data", {})]
        images += len(pngs)
        for p in pngs:
            assert _png_width(p) <= MAX_PNG_WIDTH
        if re.search(r"^\s*print\(", c.source, re.M) and not c.source.lstrip().startswith("if "):
            assert "stream" in kinds, f"{path.name} code cell {i + 1} prints but stored no text"
        if FIGURE.search(c.source):
            assert pngs, f"{path.name} code cell {i + 1} draws a figure but stored no image"
    if any(FIGURE.search(c.source) for c in code):
        assert images >= 1


# the notebooks that draw a map use pqrm_jax.plot for it (issue 30 item 4)
USES_PLOT = {"02_pqrm.ipynb": "draw_relational_map", "03_qrm_rng.ipynb": "draw_relational_map",
             "06_qlink.ipynb": "draw_link_graph", "08_hssh_local.ipynb": "draw_local_topology",
             "09_hssh_global.ipynb": "draw_topological_map"}


@pytest.mark.parametrize("name", sorted(USES_PLOT))
def test_map_figures_are_drawn_by_pqrm_jax_plot(name):
    nb = nbformat.read(Path(__file__).parent.parent / "notebooks" / name, as_version=4)
    call = f"plot.{USES_PLOT[name]}("
    cells = [c for c in nb.cells if c.cell_type == "code" and call in c.source]
    assert cells, f"{name} draws no figure with pqrm_jax.plot.{USES_PLOT[name]}"
    assert any("image/png" in o.get("data", {}) for c in cells for o in c.get("outputs", []))
