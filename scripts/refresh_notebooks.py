"""Re-execute every notebook in notebooks/ and store its outputs in the file (small).

    .venv/bin/python scripts/refresh_notebooks.py [NAME.ipynb ...]

Each notebook runs top to bottom in a fresh kernel (as tests/test_notebooks.py runs it), in a
temporary working directory. The stored outputs are kept small: execution timing metadata is
dropped, PNG images are re-encoded at most 700 px wide with a 256-colour palette, text outputs
are cut at 4000 characters, and a notebook whose outputs exceed 400 kB in total is refused (fix
the notebook). A notebook that fails is left unchanged and named; the others are refreshed
(exit status 1 if any failed). tests/test_notebooks.py checks the stored outputs.
"""

from __future__ import annotations

import base64
import io
import sys
import tempfile
from pathlib import Path

import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parent.parent
MAX_TEXT = 4000
MAX_WIDTH = 700
MAX_BYTES = 400_000


def _small_png(data: str) -> str:
    from PIL import Image

    img = Image.open(io.BytesIO(base64.b64decode(data)))
    if img.width > MAX_WIDTH:
        img = img.resize((MAX_WIDTH, round(img.height * MAX_WIDTH / img.width)),
                         Image.Resampling.LANCZOS)
    if img.mode in ("RGBA", "LA", "P"):  # flatten on white (matplotlib's figure background)
        rgba = img.convert("RGBA")
        img = Image.new("RGB", rgba.size, "white")
        img.paste(rgba, mask=rgba.getchannel("A"))
    # a 256-colour palette: plots have few colours, and this keeps stored notebooks small
    img = img.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return base64.b64encode(buf.getvalue()).decode()


def refresh(path: Path) -> int:
    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as tmp:
        NotebookClient(nb, timeout=900, kernel_name="python3",
                       resources={"metadata": {"path": tmp}}).execute()
    size = 0
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        cell.metadata.pop("execution", None)
        for out in cell.get("outputs", []):
            if out.get("output_type") == "error":
                raise RuntimeError(f"{path.name}: a cell raised {out.get('ename')}")
            if "text" in out and len(out["text"]) > MAX_TEXT:
                out["text"] = out["text"][:MAX_TEXT] + "\n... (output cut)\n"
            data = out.get("data", {})
            if "image/png" in data:
                data["image/png"] = _small_png(data["image/png"])
            size += len(str(out))
    if size > MAX_BYTES:
        raise RuntimeError(f"{path.name}: outputs are {size} bytes (> {MAX_BYTES})")
    nbformat.write(nb, path)
    return size


def main(argv: list[str]) -> int:
    names = argv or sorted(p.name for p in (ROOT / "notebooks").glob("*.ipynb"))
    failed = []
    for name in names:  # a failing notebook is left unchanged; the others are refreshed
        try:
            size = refresh(ROOT / "notebooks" / name)
        except Exception as exc:  # noqa: BLE001  (nbclient's and our errors alike)
            print(f"{name}: NOT refreshed: {type(exc).__name__}: {exc}", flush=True)
            failed.append(name)
            continue
        print(f"{name}: outputs stored ({size / 1000:.0f} kB)", flush=True)
    if failed:
        print("failed:", " ".join(failed), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
