"""Sphinx extension of the dpe5g book: execution caches that cannot go stale, and each chapter's notebook for download.

* **Fresh outputs.**  jupyter-cache keys a chapter on its own code cells only, so after an edit of ``dpe5g/`` the
  book would show the new code (``literalinclude``) beside outputs computed by the old code.  At the start of every
  build this extension hashes the files named in ``dpe5g_cache_sources`` (relative to the book's source folder;
  ``sources_digest``) and, when they changed, deletes the execution cache and marks every page
  outdated, so every chapter is re-executed.  Re-executing is cheap where the Monte Carlo cache (keyed on the code's
  syntax tree, see ``dpe5g.montecarlo``) still holds.  ``tests/test_book_cache.py`` proves it on a one-page book.
* **Download.**  The executed notebook of every chapter (``<outdir>/../jupyter_execute/<doc>.ipynb``, written by
  MyST-NB) is offered by the theme's download button as ``.ipynb`` (copied next to the page's source in
  ``_sources/``); nothing is fetched from the network.  MyST-NB moves glued values out of the cells' outputs, so
  the copy is made readable outside the book: every glue reference in the prose is replaced by its value and every
  ``{glue:figure}`` by the image (a cell attachment) and its caption (``reader_notebook``).
"""

from __future__ import annotations

import hashlib
import os
import json
import re
import shutil
from pathlib import Path

STAMP_SUFFIX = ".sources.sha256"


def sources_digest(paths: list[Path]) -> str:
    """SHA-256 over the relative names and bytes of every file under ``paths`` (files or folders), sorted;
    ``__pycache__`` and ``*.pyc`` left out."""
    h = hashlib.sha256()
    for root in paths:
        if not root.exists():
            raise ValueError(f"dpe5g_cache_sources: {str(root)!r} does not exist")
        files = [root] if root.is_file() else sorted(
            p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc")
        for f in files:
            h.update(str(f.relative_to(root.parent)).encode() + b"\0")
            h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def sync(cache: Path, sources: list[Path]) -> bool:
    """Delete ``cache`` if ``sources`` changed since the digest stored beside it (``<cache>.sources.sha256``);
    store the current digest.  Returns True when the cache was cleared (or did not exist yet)."""
    digest = sources_digest(sources)
    stamp = cache.with_name(cache.name + STAMP_SUFFIX)
    cleared = not cache.exists() or not stamp.exists() or stamp.read_text().strip() != digest
    if cleared and cache.exists():
        shutil.rmtree(cache)
    create_database(cache)
    stamp.parent.mkdir(parents=True, exist_ok=True)
    stamp.write_text(digest + "\n")
    return cleared


def create_database(cache: Path) -> None:
    """Create jupyter-cache's folder and database at ``cache`` (nothing if they exist), in Sphinx's main process.

    Each parallel reader (``scripts/build_book.py``) opens the cache and creates both when they are missing; two at
    once on a fresh clone failed the build ("table settings already exists", CI at 99ab854)."""
    from jupyter_cache.cache.db import create_db

    cache.mkdir(parents=True, exist_ok=True)
    create_db(cache).dispose()


def _exec_cache(app) -> Path:
    configured = getattr(app.env, "mystnb_config", None)
    path = getattr(configured, "execution_cache_path", None) if configured is not None else None
    return Path(path) if path else Path(app.outdir).parent / ".jupyter_cache"


def _sync(app) -> None:
    sources = [Path(app.srcdir) / s for s in app.config.dpe5g_cache_sources]
    app._dpe5g_sources_changed = bool(sources) and sync(_exec_cache(app), sources)
    if app._dpe5g_sources_changed:
        print("dpe5g_book: " + ", ".join(app.config.dpe5g_cache_sources)
              + " changed (or no execution cache yet): every chapter is re-executed")


def _outdated(app, env, added, changed, removed):
    if getattr(app, "_dpe5g_sources_changed", False):
        return sorted(env.found_docs - set(added) - set(removed))
    if _static_changed(app):  # Sphinx copies the static files only when it writes a page: write the root one
        return [app.config.root_doc]
    return []


def _static_changed(app) -> bool:
    """Whether a file of the book's html_static_path is newer than its copy in the built book."""
    src = Path(app.srcdir)
    for folder in app.config.html_static_path:
        for f in (src / folder).glob("*"):
            built = Path(app.outdir) / "_static" / f.name
            if f.is_file() and (not built.exists() or built.stat().st_mtime < f.stat().st_mtime):
                return True
    return False


def _notebook(app, docname: str) -> Path:
    return Path(app.outdir).parent / "jupyter_execute" / f"{docname}.ipynb"


def _page_context(app, pagename, templatename, context, doctree):
    if doctree is not None and _notebook(app, pagename).exists():
        context["ipynb_source"] = f"{pagename}.ipynb"
    # Jupyter Book loads sphinx-thebe even with launch_buttons.thebe false, and its inline THEBE_JS_URL script twice
    # (a console error on every page) pointing at an online CDN: the book is offline and has no live code, so no
    # page carries Thebe's scripts
    for key in ("script_files", "css_files"):
        if key in context:
            context[key] = [f for f in context[key] if not _thebe_script(f)]


def _drop_thebe_config(app, doctree, docname):
    """Remove the raw HTML that sphinx-thebe appends to every page (its kernel configuration and kernel name), and
    put a glyph the page's fonts have in place of MyST-NB's emoji."""
    from docutils import nodes

    for node in list(doctree.findall(nodes.raw)):
        if "x-thebe-config" in node.astext() or "kernelName =" in node.astext():
            node.parent.remove(node)
    # MyST-NB's execution table marks a chapter run with an emoji (U+2705) that the Debian fonts lack (an empty box
    # on the page): the check mark U+2713, which DejaVu has
    for text in list(doctree.findall(nodes.Text)):
        if "\u2705" in text:
            text.parent.replace(text, nodes.Text(str(text).replace("\u2705", "\u2713")))


def _thebe_script(js) -> bool:
    """A script or style sheet of sphinx-thebe: its loader, its CSS, or an inline script that configures it (the
    asset's repr names each)."""
    return "thebe" in str(js).lower()


_GLUE_FIGURE = re.compile(r"```\{glue:figure\}[ \t]+(\S+)\n(.*?)```", re.S)
_GLUE_ROLE = re.compile(r"\{glue(?::(text|md|any))?\}`([^`]+)`")


def reader_notebook(nb, glue: dict):
    """Replace the glue references of ``nb``'s Markdown cells by the glued values (in place; returns ``nb``).

    ``glue`` maps a key to its output (``{"data": {mime: value}}``, MyST-NB's ``<doc>.glue.json``).  ``{glue:text}``
    is formatted as MyST-NB formats it; ``{glue:md}`` pastes the Markdown; ``{glue:figure}`` becomes the image as a
    cell attachment followed by the caption.  An unknown key raises KeyError: the book build has already checked
    every key, so one missing here is a bug."""
    from myst_nb.core.variables import format_plain_text

    def role(mo):
        kind, ref = mo.group(1), mo.group(2)
        if kind == "text":
            key, fmt = ref.rsplit(":", 1) if ":" in ref else (ref, "")
            return format_plain_text(glue[key]["data"]["text/plain"], fmt)
        data = glue[ref]["data"]
        return data.get("text/markdown", data.get("text/plain", "")) if kind == "md" else data.get("text/plain", "")

    for cell in nb.cells:
        if cell.cell_type != "markdown":
            continue
        attachments = {}

        def figure(mo):
            key, body = mo.group(1), mo.group(2)
            caption = "\n".join(line for line in body.splitlines() if not line.startswith(":")).strip()
            data = glue[key]["data"]
            if "image/png" in data:
                attachments[f"{key}.png"] = {"image/png": data["image/png"]}
                shown = f"![{key}](attachment:{key}.png)"
            else:
                shown = data.get("text/html", data.get("text/plain", ""))
            return f"{shown}\n\n{caption}\n"

        cell.source = _GLUE_ROLE.sub(role, _GLUE_FIGURE.sub(figure, cell.source))
        if attachments:
            cell["attachments"] = attachments
    return nb


def _copy_notebooks(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    import nbformat

    for docname in sorted(app.env.found_docs):
        path = _notebook(app, docname)
        if not path.exists():
            continue
        nb = nbformat.read(path, as_version=4)
        glue_path = path.with_name(path.stem + ".glue.json")
        reader_notebook(nb, json.loads(glue_path.read_text()) if glue_path.exists() else {})
        dest = Path(app.outdir) / "_sources" / f"{docname}.ipynb"
        dest.parent.mkdir(parents=True, exist_ok=True)
        nbformat.write(nb, dest)


def _save_data_comments(app, what, name, obj, options, lines):
    """Before napoleon (priority 400): keep a constant's ``#:`` comment as written.  Napoleon reads the first line of
    a data or attribute docstring as "type: description", so "default cache directory: …" would show a type
    "default cache directory" (and fail the build as a broken cross-reference); the comments are prose."""
    if what in ("data", "attribute"):
        app.env.temp_data.setdefault("dpe5g_data_comments", {})[name] = list(lines)


def _restore_data_comments(app, what, name, obj, options, lines):
    """After napoleon (priority 600): put back what ``_save_data_comments`` kept."""
    kept = app.env.temp_data.get("dpe5g_data_comments", {}).pop(name, None)
    if kept is not None:
        lines[:] = kept


def _repository_paths():
    """Values in the API reference name a packaged file by its path in the repository, not on the building machine
    (``deployment.BUILTIN``'s files were shown as PosixPath('/tmp/…/dpe5g/data/…'))."""
    import sphinx.ext.autodoc as autodoc

    root = Path(__file__).resolve().parents[2]
    described = autodoc.object_description

    def relative(obj, *args, **kwargs):
        text = described(obj, *args, **kwargs)
        return re.sub(r"PosixPath\('([^']*)'\)", lambda m: repr(os.path.relpath(m.group(1), root)), text)

    autodoc.object_description = relative


def _author_year_style():
    """A pybtex style, "dpe5g_author_year", whose bibliography labels read as the in-text author_year citations do
    ("Li et al., 2025", "3GPP TR 38.901, 2022"; a, b … after the year where two would be the same), instead of the
    default alpha labels ("LVX25")."""
    from pybtex.plugin import register_plugin
    from pybtex.style.formatting.unsrt import Style as Unsrt
    from pybtex.style.labels import BaseLabelStyle

    def names(entry):
        people = entry.persons.get("author") or entry.persons.get("editor") or []
        last = [" ".join(p.last_names).replace("{", "").replace("}", "") for p in people]
        if len(last) > 2:
            return f"{last[0]} et al."
        return " and ".join(last) or entry.key

    class Labels(BaseLabelStyle):
        def format_labels(self, sorted_entries):
            labels = [f"{names(e)}, {e.fields.get('year', '')}" for e in sorted_entries]
            seen = {}
            for label in labels:
                n = labels.count(label)
                seen[label] = seen.get(label, 0) + 1
                yield label if n == 1 else label + "abcdefghijklmnopqrstuvwxyz"[seen[label] - 1]

    class Style(Unsrt):
        default_label_style = Labels
        default_sorting_style = "author_year_title"

    register_plugin("pybtex.style.formatting", "dpe5g_author_year", Style)


def setup(app):
    os.environ["DPE5G_BOOK_BUILD"] = "1"  # (dpe5g.figures.registry.BOOK_BUILD_ENV: the chapters' kernels glue for the book only)
    app.add_config_value("dpe5g_cache_sources", [], "env")
    _author_year_style()
    app.setup_extension("sphinx.ext.autodoc")  # (the API reference; its object descriptions below)
    app.connect("autodoc-process-docstring", _save_data_comments, priority=400)  # around napoleon's (500)
    app.connect("autodoc-process-docstring", _restore_data_comments, priority=600)
    _repository_paths()
    app.connect("builder-inited", _sync, priority=900)  # after MyST-NB has set its execution cache path
    app.connect("env-get-outdated", _outdated)
    app.connect("html-page-context", _page_context)
    app.connect("doctree-resolved", _drop_thebe_config, priority=900)  # after sphinx-thebe's own handler (500)
    app.connect("build-finished", _copy_notebooks)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
