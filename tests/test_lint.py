"""Module boundaries: a module's ``_private`` names stay inside it (the style guide), checked on the AST."""

import ast
import re
from pathlib import Path

PKG = Path(__file__).resolve().parent.parent / "dpe5g"
CHAPTERS = Path(__file__).resolve().parent.parent / "chapters"
MODULES = {p.stem for p in PKG.glob("*.py")}


def private_uses(source: str, own: str) -> list[str]:
    """``mod._name`` attribute uses and ``from .mod import _name`` imports of another package module's private
    names in ``source`` (a module named with a leading underscore, like ``_checks``, is a shared helper module and
    its public names may be used)."""
    tree = ast.parse(source)
    aliases = {}
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.level == 1 or (node.module or "").startswith("dpe5g")):
            mod = (node.module or "").removeprefix("dpe5g").lstrip(".")
            for a in node.names:
                if not mod and a.name in MODULES:  # from . import dpe
                    aliases[a.asname or a.name] = a.name
                elif mod and mod != own and a.name.startswith("_"):
                    bad.append(f"from {mod} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.attr.startswith("_")
                and not node.attr.startswith("__") and aliases.get(node.value.id, own) != own):
            bad.append(f"{node.value.id}.{node.attr} (line {node.lineno})")
    return bad


def test_private_names_stay_in_their_module():
    bad = {p.name: private_uses(p.read_text(), p.stem) for p in PKG.glob("*.py")}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_chapters_use_public_names_only():
    pat = re.compile(r"\b(" + "|".join(sorted(m for m in MODULES if not m.startswith("_"))) + r")\._[a-z]\w*")
    bad = {p.name: pat.findall(p.read_text()) for p in CHAPTERS.glob("*.md")}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_lint_catches_a_private_call():
    src = "from . import dpe, _checks\nx = dpe._ml_cost(1)\ny = _checks.integer('a', 1, 0, 2)\n"
    assert private_uses(src, "otdoa") == ["dpe._ml_cost (line 2)"]
    assert private_uses("from .dpe import _lookup\n", "otdoa") == ["from dpe import _lookup"]
    assert private_uses("from . import dpe\nx = dpe._lookup\n", "dpe") == []
