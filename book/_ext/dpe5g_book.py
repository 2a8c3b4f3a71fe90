"""Sphinx extension of the dpe5g book: execution caches that cannot go stale, and each chapter's notebook for download.

* **Fresh outputs.**  jupyter-cache keys a chapter on its own code cells only, so after an edit of ``dpe5g/`` the
  book would show the new code (``literalinclude``) beside outputs computed by the old code.  At the start of every
  build this extension hashes the files named in ``dpe5g_cache_sources`` (relative to the book's source folder;
  ``scripts/book_cache.py`` does the hashing) and, when they changed, deletes the execution cache and marks every page
  outdated, so every chapter is re-executed.  Re-executing is cheap where the Monte Carlo cache (keyed on the code's
  syntax tree, see ``dpe5g.montecarlo``) still holds.  ``tests/test_book_cache.py`` proves it on a one-page book.
* **Download.**  The executed notebook of every chapter (``<outdir>/../jupyter_execute/<doc>.ipynb``, written by
  MyST-NB) is copied next to the page's source in ``_sources/`` and offered by the theme's download button as
  ``.ipynb``; nothing is fetched from the network.
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_SCRIPT = _HERE.parents[1] / "scripts" / "book_cache.py"


def _book_cache():
    spec = importlib.util.spec_from_file_location("book_cache", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _exec_cache(app) -> Path:
    configured = getattr(app.env, "mystnb_config", None)
    path = getattr(configured, "execution_cache_path", None) if configured is not None else None
    return Path(path) if path else Path(app.outdir).parent / ".jupyter_cache"


def _sync(app) -> None:
    sources = [Path(app.srcdir) / s for s in app.config.dpe5g_cache_sources]
    app._dpe5g_sources_changed = bool(sources) and _book_cache().sync(_exec_cache(app), sources)
    if app._dpe5g_sources_changed:
        print("dpe5g_book: " + ", ".join(app.config.dpe5g_cache_sources)
              + " changed (or no execution cache yet): every chapter is re-executed")


def _outdated(app, env, added, changed, removed):
    if getattr(app, "_dpe5g_sources_changed", False):
        return sorted(env.found_docs - set(added) - set(removed))
    return []


def _notebook(app, docname: str) -> Path:
    return Path(app.outdir).parent / "jupyter_execute" / f"{docname}.ipynb"


def _page_context(app, pagename, templatename, context, doctree):
    if doctree is not None and _notebook(app, pagename).exists():
        context["ipynb_source"] = f"{pagename}.ipynb"


def _copy_notebooks(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    for docname in sorted(app.env.found_docs):
        nb = _notebook(app, docname)
        if nb.exists():
            dest = Path(app.outdir) / "_sources" / f"{docname}.ipynb"
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(nb, dest)


def setup(app):
    app.add_config_value("dpe5g_cache_sources", [], "env")
    app.connect("builder-inited", _sync, priority=900)  # after MyST-NB has set its execution cache path
    app.connect("env-get-outdated", _outdated)
    app.connect("html-page-context", _page_context)
    app.connect("build-finished", _copy_notebooks)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
