"""The API reference's docstrings follow one convention, NumPy style, as ``sphinx.ext.napoleon`` renders it: every
public function, method and class listed on ``book/api.md`` names each of its parameters (a dataclass each of its
fields) under "Parameters" (or "Attributes"), a function that returns a value has a "Returns" (or "Yields")
section, and every docstring, after napoleon's conversion, is reStructuredText that docutils reads without a warning
(the book's build would otherwise fail on it, or show it garbled)."""

import ast
import dataclasses
import importlib
import inspect
import re
import textwrap
from pathlib import Path

import docutils.core
import docutils.utils
import pytest
import yaml
from sphinx.ext.napoleon import Config, NumpyDocstring

ROOT = Path(__file__).resolve().parent.parent
API_MODULES = re.findall(r"automodule:: (dpe5g\.[\w.]+)", (ROOT / "book" / "api.md").read_text())
#: napoleon's settings as the book has them (book/_config.yml)
NAPOLEON = Config(**{k: v for k, v in yaml.safe_load((ROOT / "book" / "_config.yml").read_text())["sphinx"]["config"]
                     .items() if k.startswith("napoleon_")})
HEADER = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.M)


def sections(doc: str) -> dict[str, str]:
    """{section title: its body} of a NumPy-style docstring (the text before the first section under "")."""
    parts = HEADER.split(doc)
    return {"": parts[0]} | {parts[i]: parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def named(body: str) -> set[str]:
    """The names a Parameters/Attributes section documents: each unindented ``name[, name...] : type`` line (a
    line without a type too)."""
    out = set()
    for line in body.splitlines():
        if line and not line[0].isspace():
            out.update(n.strip().lstrip("*") for n in line.split(" : ")[0].split(","))
    return out


def returns_value(fn) -> bool:
    """Whether ``fn``'s own body (not a nested function's) has a ``return <value>`` or a ``yield``."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError):
        return False
    stack = list(ast.iter_child_nodes(tree.body[0]))
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, (ast.Yield, ast.YieldFrom)):
            return True
        if isinstance(node, ast.Return) and node.value is not None and not (
                isinstance(node.value, ast.Constant) and node.value.value is None):
            return True
        stack.extend(ast.iter_child_nodes(node))
    return False


def members(module) -> list[tuple[str, object]]:
    """(qualified name, object) of what ``automodule :members:`` lists for ``module``: its own public functions
    (jitted ones by the function they wrap) and classes with a docstring, and their own public methods and
    properties."""
    out = []
    for name, obj in vars(module).items():
        obj = getattr(obj, "__wrapped__", obj) if callable(obj) and not inspect.isclass(obj) else obj  # (jax.jit)
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__ or not obj.__doc__:
            continue
        if inspect.isfunction(obj) or inspect.isclass(obj):
            out.append((f"{module.__name__}.{name}", obj))
        if inspect.isclass(obj):
            for mname, m in vars(obj).items():
                target = m.fget if isinstance(m, property) else getattr(m, "__func__", m)
                if not mname.startswith("_") and inspect.isfunction(target) and target.__doc__:
                    out.append((f"{module.__name__}.{name}.{mname}", m))
    return out


def problems(obj) -> list[str]:
    """What ``obj``'s docstring lacks under the convention (empty when it follows it)."""
    doc = inspect.cleandoc(obj.__doc__)
    found = sections(doc)
    bad = []
    if isinstance(obj, property):
        return bad
    if inspect.isclass(obj):
        wanted = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else []
        have = named(found.get("Attributes", "")) | named(found.get("Parameters", ""))
        bad += [f"field {n!r} not under Attributes" for n in wanted if n not in have]
        return bad
    fn = getattr(obj, "__func__", obj)
    params = [p for p in inspect.signature(fn).parameters if p not in ("self", "cls")]
    have = named(found.get("Parameters", "")) | named(found.get("Other Parameters", ""))
    bad += [f"parameter {p!r} not under Parameters" for p in params if p not in have]
    bad += [f"documents {p!r}, which is not a parameter" for p in sorted(have - set(params))]
    if returns_value(fn) and not ({"Returns", "Yields"} & found.keys()):
        bad.append("returns a value but has no Returns section")
    return bad


def rst_warnings(doc: str) -> list[str]:
    """docutils' warnings (and worse) on ``doc`` after napoleon's conversion."""
    text = str(NumpyDocstring(inspect.cleandoc(doc), NAPOLEON))
    messages = []
    settings = {"report_level": 5, "halt_level": 5, "warning_stream": False}
    tree = docutils.core.publish_doctree(text, settings_overrides=settings)
    for node in tree.findall(docutils.nodes.system_message):
        if node["level"] >= docutils.utils.Reporter.WARNING_LEVEL:
            messages.append(f"line {node.get('line')}: {node.astext().splitlines()[0]}")
    return messages


@pytest.mark.parametrize("module_name", API_MODULES)
def test_docstrings_follow_numpy_style(module_name):
    module = importlib.import_module(module_name)
    bad = {name: found for name, obj in members(module) if (found := problems(obj))}
    assert not bad, bad


@pytest.mark.parametrize("module_name", API_MODULES)
def test_docstrings_are_valid_restructuredtext(module_name):
    module = importlib.import_module(module_name)
    docs = [(module_name, module.__doc__ or "")] + [
        (name, (obj.fget if isinstance(obj, property) else obj).__doc__) for name, obj in members(module)]
    bad = {name: found for name, doc in docs if (found := rst_warnings(doc))}
    assert not bad, bad


def test_the_convention_check_finds_what_is_missing():
    def documented(a, b=1):
        """Sum.

        Parameters
        ----------
        a, b : float
            Terms.

        Returns
        -------
        float
        """
        return a + b

    def undocumented(a, b=1):
        """Sum of a and b."""
        return a + b

    @dataclasses.dataclass
    class Pair:
        """Two numbers.

        Attributes
        ----------
        a : float
            The first.
        """

        a: float
        b: float

    assert problems(documented) == []
    assert problems(undocumented) == ["parameter 'a' not under Parameters", "parameter 'b' not under Parameters",
                                      "returns a value but has no Returns section"]
    assert problems(Pair) == ["field 'b' not under Attributes"]
    assert rst_warnings(documented.__doc__) == []
    assert rst_warnings("Text.\n\n  indented\nback\n")


def test_the_book_renders_numpy_sections():
    assert NAPOLEON.napoleon_numpy_docstring and not NAPOLEON.napoleon_google_docstring
    text = str(NumpyDocstring("Sum.\n\nAttributes\n----------\na : float (M,)\n    Metres.\n", NAPOLEON))
    assert ":Attributes: **a** (*float (M,)*) -- Metres." in text
