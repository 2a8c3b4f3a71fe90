"""Module boundaries: a module's ``_private`` names stay inside it (the style guide), in the package, the tests, the
benchmarks, the scripts and the chapters (their code cells and the code they show), checked on the AST."""

import ast
import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "dpe5g"
CHAPTERS = ROOT / "chapters"
#: every module of the package, in its subpackages too
SOURCES = sorted(PKG.rglob("*.py"))
OUTSIDE = [p for d in ("tests", "benchmarks", "scripts") for p in sorted((ROOT / d).rglob("*.py"))]


def module_of(path: Path) -> tuple[str, str]:
    """A package file's module name inside ``dpe5g`` ("cost", "phy.channel"; a subpackage's ``__init__``: the
    subpackage's, "phy"; the top one's: "__init__") and the package its relative imports resolve against."""
    parts = path.relative_to(PKG).with_suffix("").parts
    package = ".".join(("dpe5g", *parts[:-1]))
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]) or "__init__", package
    return ".".join(parts), package


MODULES = {module_of(p)[0] for p in SOURCES}

#: the top level's public names, each its module (``from dpe5g import dpe`` is ``dpe5g.receivers.dpe``)
PUBLIC = dict(__import__("dpe5g").PUBLIC)


def module_named(mod: str, name: str) -> str | None:
    """The package module that ``name`` imported from ``mod`` (``imported_module``) is, or None for another name."""
    sub = f"{mod}.{name}" if mod else name
    return sub if sub in MODULES else PUBLIC.get(name) if not mod else None


def imported_module(node: ast.ImportFrom, package: str) -> str | None:
    """The module (inside ``dpe5g``, "" for the package itself) that ``from X import …`` imports from: relative
    imports of any depth resolved against ``package``; None for a module outside ``dpe5g``."""
    if node.level:
        full = importlib.util.resolve_name("." * node.level + (node.module or ""), package)
    elif node.module == "dpe5g" or (node.module or "").startswith("dpe5g."):
        full = node.module
    else:
        return None
    return full.removeprefix("dpe5g").lstrip(".")


def private_uses(source: str, own: str, package: str = "dpe5g") -> list[str]:
    """``mod._name`` attribute uses and ``from .mod import _name`` / ``from dpe5g.mod import _name`` imports of
    another package module's private names in ``source``; ``own`` is the module the source belongs to (``module_of``;
    "" outside the package) and ``package`` the package its relative imports resolve against.  ``import dpe5g`` then
    ``dpe5g._name`` counts as the package's own ``__init__``'s private name.  A module named with a leading
    underscore, like ``_checks``, is a shared helper module and its public names may be used."""
    tree = ast.parse(source)
    aliases = {}
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "dpe5g" or a.name.startswith("dpe5g."):
                    aliases[a.asname or a.name.split(".")[0]] = "__init__" if a.asname is None else a.name[6:]
        if isinstance(node, ast.ImportFrom) and (mod := imported_module(node, package)) is not None:
            for a in node.names:
                if (sub := module_named(mod, a.name)) is not None:  # from . import dpe, from ..phy import channel
                    aliases[a.asname or a.name] = sub
                elif a.name.startswith("_") and not a.name.startswith("__") and (mod or "__init__") != own:
                    bad.append(f"from {mod or 'dpe5g'} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.attr.startswith("_")
                and not node.attr.startswith("__") and node.value.id in aliases and aliases[node.value.id] != own):
            bad.append(f"{node.value.id}.{node.attr} (line {node.lineno})")
    return bad


def chapter_code(text: str) -> str:
    """The code cells of a MyST notebook, their option lines (``:tags:`` or a ``---`` YAML block) left out."""
    cells = [re.sub(r"\A---\n.*?\n---\n", "", c, flags=re.S)
             for c in re.findall(r"```\{code-cell\}[^\n]*\n(.*?)```", text, re.S)]
    return "\n\n".join("\n".join(line for line in c.split("\n") if not line.startswith((":", "%", "---")))
                       for c in cells)


def test_private_names_stay_in_their_module():
    bad = {str(p.relative_to(PKG)): found for p in SOURCES if (found := private_uses(p.read_text(), *module_of(p)))}
    assert not bad, bad


def test_tests_benchmarks_and_scripts_use_public_names_only():
    bad = {str(p.relative_to(ROOT)): found for p in OUTSIDE if (found := private_uses(p.read_text(), ""))}
    assert not bad, bad


def test_chapters_use_and_show_public_names_only():
    shown = re.compile(r"```\{literalinclude\} [^\n]*\n(?::[\w-]+:[^\n]*\n)*?:pyobject: ([\w.]+)")
    bad = {}
    for p in sorted(CHAPTERS.glob("*.md")):
        text = p.read_text()
        found = private_uses(chapter_code(text), "")
        found += [f"literalinclude {name}" for name in shown.findall(text) if any(
            part.startswith("_") and not part.startswith("__") for part in name.split("."))]
        if found:
            bad[p.name] = found
    assert not bad, bad


def test_the_lint_catches_a_private_use():
    src = "from . import dpe\nfrom ..common import _checks\nx = dpe._ml_cost(1)\ny = _checks.integer('a', 1, 0, 2)\n"
    assert private_uses(src, "receivers.otdoa", "dpe5g.receivers") == ["dpe._ml_cost (line 3)"]
    assert private_uses("from .dpe import _lookup\n", "receivers.otdoa", "dpe5g.receivers") == [
        "from receivers.dpe import _lookup"]
    assert private_uses("from dpe5g.receivers.cost import _lookup\n", "") == ["from receivers.cost import _lookup"]
    assert private_uses("from dpe5g import _xla\n", "") == ["from dpe5g import _xla"]
    assert private_uses("import dpe5g\nx = dpe5g._xla\n", "") == ["dpe5g._xla (line 2)"]
    assert private_uses("from dpe5g.receivers import cost as c\nx = c._lookup\n", "") == ["c._lookup (line 2)"]
    assert private_uses("from . import dpe\nx = dpe._lookup\n", "receivers.dpe", "dpe5g.receivers") == []
    assert private_uses("from dpe5g.receivers import cost\nx = cost.lookup\n", "") == []
    # relative imports of depth 2 resolve against the module's package
    assert private_uses("from ..receivers.cost import _lookup\n", "phy.channel", "dpe5g.phy") == [
        "from receivers.cost import _lookup"]
    assert private_uses("from ..receivers import dpe\nx = dpe._ml_cost(1)\n", "phy.channel", "dpe5g.phy") == [
        "dpe._ml_cost (line 2)"]
    text = "```{code-cell} ipython3\n:tags: [hide-input]\nfrom dpe5g.receivers import cost\ncost._lookup(1)\n```\n"
    assert private_uses(chapter_code(text), "") == ["cost._lookup (line 2)"]


#: the style guide's sizes: a function fits on a screen (a test fails past it); a module is as long as its one concept
#: needs, and one past REVIEW_MODULE_LINES is listed for a reviewer's look (``long_modules``), not failed
MAX_FUNCTION_LINES = 80
REVIEW_MODULE_LINES = 800


def too_long(source: str) -> list[str]:
    """The functions of ``source`` longer than ``MAX_FUNCTION_LINES`` (decorators left out)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION_LINES:
                out.append(f"{node.name}: {n} lines")
    return out


def long_modules() -> list[str]:
    """The package's modules longer than ``REVIEW_MODULE_LINES``, "path: N lines": for a reviewer to ask whether each
    still holds one concept (``conftest.py`` prints them after every run)."""
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in SOURCES}
    return [f"{name}: {n} lines" for name, n in sorted(sizes.items()) if n > REVIEW_MODULE_LINES]


def concept_line(source: str) -> str | None:
    """The first line of a module's docstring, where the module names the one concept it holds; None without one."""
    doc = ast.get_docstring(ast.parse(source), clean=False)
    first = (doc or "").strip().splitlines()
    return first[0].strip() if first and first[0].strip() else None


def test_functions_fit_on_a_screen():
    bad = {str(p.relative_to(PKG)): found for p in SOURCES if (found := too_long(p.read_text()))}
    assert not bad, bad


def test_every_module_names_its_concept_first():
    """Each module's docstring opens with the concept it holds (the rule that replaced a cap on its length)."""
    missing = [str(p.relative_to(PKG)) for p in SOURCES if concept_line(p.read_text()) is None]
    assert not missing, f"modules without a docstring naming their concept in its first line: {missing}"


def test_the_size_and_concept_checks_count():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    assert too_long(f"def f():\n{body}\n") == ["f: 81 lines"]
    assert too_long(f"def f():\n{body[:-len(f'    x{MAX_FUNCTION_LINES - 1} = {MAX_FUNCTION_LINES - 1}') - 1]}\n") == []
    assert too_long("x = 1\n" * (REVIEW_MODULE_LINES + 1)) == []  # a long module is listed, not failed
    assert concept_line('"""The ML cost of DPE.\n\nMore."""\nx = 1\n') == "The ML cost of DPE."
    assert concept_line('"""\n\n"""\n') is None and concept_line("x = 1\n") is None


def missing_names(source: str, own: str, package: str = "dpe5g") -> list[str]:
    """``mod.name`` reads in ``source`` of a package module ``mod`` (imported as ``from dpe5g import mod``, ``from .
    import mod`` or from a subpackage, ``from ..phy import mod``) that the module does not define: a name that moved
    or went, which no test may run.  ``own`` and ``package`` as for ``private_uses``."""
    import importlib

    tree = ast.parse(source)
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (mod := imported_module(node, package)) is not None:
            for a in node.names:
                if (sub := module_named(mod, a.name)) is not None:
                    aliases[a.asname or a.name] = sub
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            mod = importlib.import_module(f"dpe5g.{aliases[node.value.id]}")
            if aliases[node.value.id] != own and not hasattr(mod, node.attr):
                bad.append(f"{node.value.id}.{node.attr} (line {node.lineno})")
    return bad


def test_every_module_name_read_exists():
    files = {p: module_of(p) for p in SOURCES} | {p: ("", "dpe5g") for p in OUTSIDE}
    bad = {str(p.relative_to(ROOT)): found for p, own in sorted(files.items())
           if (found := missing_names(p.read_text(), *own))}
    bad |= {p.name: found for p in sorted(CHAPTERS.glob("*.md"))
            if (found := missing_names(chapter_code(p.read_text()), ""))}
    assert not bad, bad


def test_the_name_check_sees_a_moved_name():
    assert missing_names("from dpe5g.receivers import correlogram\ncorrelogram.mix_parts(1)\n", "") == [
        "correlogram.mix_parts (line 2)"]
    assert missing_names("from dpe5g.receivers import receiver\nreceiver.mix_parts(1)\n", "") == []
    # the top level's public names (``dpe5g.PUBLIC``) are their modules
    assert missing_names("from dpe5g import cost\ncost.no_such_name(1)\n", "") == ["cost.no_such_name (line 2)"]


def book_sources() -> dict:
    """Every page of the book (chapters and book/*.md) and every module whose docstrings the book shows."""
    pages = sorted(CHAPTERS.glob("*.md")) + sorted((ROOT / "book").glob("*.md")) + SOURCES
    return {str(p.relative_to(ROOT)): p.read_text() for p in pages}


def test_no_generated_prose_and_no_typed_chapter_numbers():
    """The book's sentences are written in its pages, not built by code: no ``{glue:md}`` (numbers are glued with
    ``{glue:text}``, and a sentence that depends on them has a check cell).  Chapters are referred to by
    ``{numref}``/``{ref}`` (or, in code and docstrings, by their subject), never by a typed number that a
    renumbering would break."""
    generated = [name for name, text in book_sources().items() if "{glue:md}" in text]
    typed = [f"{name}:{text[:m.start()].count(chr(10)) + 1}" for name, text in book_sources().items()
             for m in re.finditer(r"\bChapters? \d", text)]
    assert not generated, f"{{glue:md}} (prose built by code) in {generated}"
    assert not typed, f"typed chapter numbers at {typed}"


def test_no_prose_line_is_a_myst_comment():
    """MyST reads a line that starts with ``%`` as a comment and drops it: a wrapped sentence whose line begins
    with "% of the trials" silently loses that line."""
    dropped = []
    for name, text in book_sources().items():
        if not name.endswith(".md"):
            continue
        fence = False
        for k, line in enumerate(text.splitlines(), 1):
            if line.lstrip().startswith("```"):
                fence = not fence
            elif not fence and line.startswith("%"):
                dropped.append(f"{name}:{k}")
    assert not dropped, f"lines MyST drops as comments: {dropped}"


def test_the_top_level_names_load_their_modules():
    """``from dpe5g import dpe`` (``PUBLIC``) loads its module silently; a module of the flat layout (``MOVED``) loads
    with a DeprecationWarning naming its new place; neither shadows a subpackage."""
    import importlib
    import warnings

    import pytest

    import dpe5g

    packages = {p.parent.name for p in PKG.glob("*/__init__.py")}
    assert not (set(dpe5g.PUBLIC) | set(dpe5g.MOVED)) & packages
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name, path in dpe5g.PUBLIC.items():
            assert getattr(dpe5g, name) is importlib.import_module(f"dpe5g.{path}")
    for name, path in dpe5g.MOVED.items():
        with pytest.warns(DeprecationWarning, match=rf"dpe5g\.{name} moved to dpe5g\.{path}"):
            assert getattr(dpe5g, name) is importlib.import_module(f"dpe5g.{path}")
    with pytest.raises(AttributeError, match="no_such_module"):
        dpe5g.no_such_module  # noqa: B018
