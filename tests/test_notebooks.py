"""A chapter re-executed as a notebook (``make chapter``, ``make lab``: jupytext reads it, nbclient runs it, no book
is building) shows the numbers its prose glues and its figures in the cells' outputs, not only as glue records."""

import os
import subprocess
import sys
from pathlib import Path

import nbformat

from dpe5g.figures import registry

ROOT = Path(__file__).resolve().parent.parent


def test_a_chapter_run_as_a_notebook_shows_its_numbers_and_figures(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != registry.BOOK_BUILD_ENV}
    r = subprocess.run([sys.executable, "scripts/run_chapter.py", "01", "--out", str(tmp_path)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-3000:]
    (path,) = tmp_path.glob("01_*.ipynb")
    outputs = [o for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code" for o in c.outputs]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "cp_samples = 288\n" in text and "ds_ns = 65" in text, text[:2000]
    images = [o for o in outputs if o.output_type == "display_data" and "image/png" in o.get("data", {})]
    assert len(images) >= 5  # Figs. 1-5
    assert not any(o.output_type == "stream" and o.name == "stderr" for o in outputs)
