"""The book cannot show outputs of old code: a change under ``dpe5g/`` re-executes the chapters.

A one-page book with its own module is built with the book's extension (``book/_ext/dpe5g_book.py``), the module
is changed and the book rebuilt.  Without the extension's source list the rebuilt page keeps the old output (the
defect: jupyter-cache keys on the page's cells only); with it the page shows the new one.  The executed notebook is
offered for download.
"""

import re
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
JB = Path(sys.executable).parent / "jupyter-book"

PAGE = """---
jupytext:
  text_representation:
    extension: .md
    format_name: myst
kernelspec:
  display_name: Python 3
  language: python
  name: python3
---
# Page

```{code-cell} ipython3
%matplotlib inline
import sys; sys.path.insert(0, "pkgx")
import mod
print(f"VALUE={mod.VALUE}")
from IPython.display import Markdown
from matplotlib.figure import Figure
from myst_nb import glue
fig = Figure(figsize=(2, 1)); fig.subplots().plot([0, 1])
glue("double", 2.0 * mod.VALUE, display=False)
glue("pic", fig, display=False)
glue("pic_caption", Markdown("**A caption.**"), display=False)
```

Twice the value is {glue:text}`double:.1f`.

```{glue:figure} pic
:name: pic

{glue:md}`pic_caption`
```
"""


def _book(tmp: Path, sources: list[str]) -> str:
    cfg = {"title": "t", "only_build_toc_files": True, "execute": {"execute_notebooks": "cache"},
           "html": {"use_download_button": True},
           "sphinx": {"local_extensions": {"dpe5g_book": str(ROOT / "book" / "_ext")},
                      "config": {"dpe5g_cache_sources": sources}}}
    (tmp / "_config.yml").write_text(yaml.safe_dump(cfg))
    r = subprocess.run([str(JB), "build", str(tmp), "--path-output", str(tmp), "-W", "-n"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return (tmp / "_build" / "html" / "page.html").read_text()


def test_changed_module_re_executes_the_page(tmp_path):
    (tmp_path / "pkgx").mkdir()
    mod = tmp_path / "pkgx" / "mod.py"
    mod.write_text("VALUE = 1\n")
    (tmp_path / "_toc.yml").write_text("format: jb-book\nroot: page\n")
    (tmp_path / "page.md").write_text(PAGE)

    assert "VALUE=1" in _book(tmp_path, ["pkgx"])
    mod.write_text("VALUE = 2\n")
    assert "VALUE=1" in _book(tmp_path, []), "jupyter-cache alone re-executes on a module change: test is moot"
    html = _book(tmp_path, ["pkgx"])
    assert "VALUE=2" in html and "VALUE=1" not in html

    # the executed notebook is downloadable from the page, with the glued values and figure in its prose
    assert "_sources/page.ipynb" in html and "Twice the value is 4.0" in re.sub(r"<[^>]+>", "", html)
    import nbformat

    nb = nbformat.read(tmp_path / "_build" / "html" / "_sources" / "page.ipynb", as_version=4)
    nbformat.validate(nb)
    assert "VALUE=2" in str([c.outputs for c in nb.cells if c.cell_type == "code"])
    prose = "\n".join(c.source for c in nb.cells if c.cell_type == "markdown")
    assert "{glue" not in prose and "Twice the value is 4.0" in prose and "**A caption.**" in prose
    assert any("pic.png" in c.get("attachments", {}) for c in nb.cells)


def test_book_config_watches_the_package_the_pins_and_the_store():
    cfg = yaml.safe_load((ROOT / "book" / "_config.yml").read_text())
    assert set(cfg["sphinx"]["config"]["dpe5g_cache_sources"]) == {"dpe5g", "environment.txt", "figures/trials"}
    assert cfg["sphinx"]["local_extensions"] == {"dpe5g_book": "_ext"}  # relative to book/_config.yml


def test_sources_digest_follows_bytes(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("dpe5g_book", ROOT / "book" / "_ext" / "dpe5g_book.py")
    bc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bc)
    (tmp_path / "src").mkdir()
    f = tmp_path / "src" / "a.py"
    f.write_text("x = 1  # comment\n")
    cache = tmp_path / "cache"
    assert bc.sync(cache, [tmp_path / "src"]) is True
    (cache / "kept").write_text("")
    assert bc.sync(cache, [tmp_path / "src"]) is False and (cache / "kept").exists()
    f.write_text("x = 1  # another comment\n")
    assert bc.sync(cache, [tmp_path / "src"]) is True and not (cache / "kept").exists()
    (tmp_path / "src" / "__pycache__").mkdir()
    (tmp_path / "src" / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"\0")
    assert bc.sync(cache, [tmp_path / "src"]) is False


def test_sync_leaves_the_execution_cache_database_for_the_parallel_readers(tmp_path):
    """After ``sync`` the readers only open jupyter-cache's database: its tables exist (two readers creating them at
    once failed a fresh parallel build)."""
    import importlib.util
    import sqlite3

    spec = importlib.util.spec_from_file_location("dpe5g_book", ROOT / "book" / "_ext" / "dpe5g_book.py")
    bc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bc)
    (tmp_path / "src").mkdir()
    cache = tmp_path / "_build" / ".jupyter_cache"
    assert bc.sync(cache, [tmp_path / "src"]) is True
    with sqlite3.connect(cache / "global.db") as db:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert {"settings", "nbcache", "nbproject"} <= tables
