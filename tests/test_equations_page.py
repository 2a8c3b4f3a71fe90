"""book/equations.md maps every numbered equation of the paper to its code and its test; the map must stay true."""

import ast
import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "book" / "equations.md"
N_EQUATIONS = 11  # equations (1)–(11) of the compiled paper


def _rows():
    """{equation number: (the functions that implement it, the tests that check it)} from the page's list: one item
    per equation, "- **Eq. {ref}`(N) <eq-N>`**: what.  Implemented by {py:func}`…`; checked by `tests/…::…`; …"."""
    rows = {}
    for line in PAGE.read_text().splitlines():
        m = re.match(r"- \*\*Eq\. \{ref\}`\((\d+)\) <eq-(\d+)>`\*\*", line)
        if m:
            assert m.group(1) == m.group(2), f"eq. ({m.group(1)}) links to eq-{m.group(2)}"
            impl = line.split("Implemented by", 1)[1].split("; checked by", 1)
            rows[int(m.group(1))] = (re.findall(r"\{py:func\}`(dpe5g\.[\w.]+)`", impl[0]),
                                     re.findall(r"`(tests/[\w/.]+::\w+)`", impl[1]))
    return rows


def _tests_in(path: Path) -> dict:
    tree = ast.parse(path.read_text())
    return {n.name: ast.get_source_segment(path.read_text(), n) for n in tree.body if isinstance(n, ast.FunctionDef)}


def test_every_equation_has_code_and_a_test():
    rows = _rows()
    assert sorted(rows) == list(range(1, N_EQUATIONS + 1))
    for n, (funcs, tests) in rows.items():
        assert funcs and tests, f"eq. ({n}): no function or no test named"
        names = []
        for dotted in funcs:
            mod, name = dotted.rsplit(".", 1)
            fn = getattr(importlib.import_module(mod), name)
            cited = {int(x) for a, b in re.findall(r"[Ee]qs?\. \((\d+)\)(?:[–-]\((\d+)\))?", fn.__doc__ or "")
                     for x in (range(int(a), int(b) + 1) if b else [a])}
            assert n in cited, f"{dotted}: its docstring does not cite eq. ({n}) (cites {sorted(cited)})"
            names.append(name)
        for t in tests:
            path, name = t.split("::")
            src = _tests_in(ROOT / path)
            assert name in src, f"eq. ({n}): {t} does not exist"
            assert any(f in src[name] for f in names), f"eq. ({n}): {t} does not call {names}"


def test_chapters_number_equations_as_the_compiled_paper():
    """Displayed equations carry the paper's number (``\\tag{N}``), never a Sphinx number (``:label:``), and prose and
    docstrings cite only equations the paper has."""
    texts = {p: p.read_text() for p in sorted((ROOT / "chapters").glob("*.md"))}
    texts.update({p: p.read_text() for p in sorted((ROOT / "dpe5g").rglob("*.py"))})
    texts[ROOT / "README.md"] = (ROOT / "README.md").read_text()
    for path, text in texts.items():
        assert not re.search(r"```\{math\}\n(:\w+:.*\n)*:label:", text), f"{path.name}: a Sphinx-numbered equation"
        tags = [int(n) for n in re.findall(r"\\tag\{(\d+)\}", text)]
        cited = [int(n) for n in re.findall(r"[Ee]qs?\. \((\d+)\)", text)]
        assert all(1 <= n <= N_EQUATIONS for n in tags + cited), f"{path.name}: cites an equation the paper lacks"


def test_the_api_reference_lists_every_public_module():
    """book/api.md documents (automodule) every module of dpe5g a user can import, except the command line's, and
    introduces each subpackage but the command line by its summary."""
    root = Path(__file__).resolve().parent.parent
    pkg = root / "dpe5g"
    modules = {".".join(p.relative_to(pkg).with_suffix("").parts) for p in pkg.rglob("*.py")
               if not any(part.startswith("_") for part in p.relative_to(pkg).parts)}
    packages = {p.parent.relative_to(pkg).as_posix() for p in pkg.glob("*/__init__.py")}
    wanted = {m for m in modules if not m.startswith("cli.")} | (packages - {"cli"})
    listed = set(re.findall(r"^\.\. automodule:: dpe5g\.([\w.]+)$", (root / "book" / "api.md").read_text(), re.M))
    assert listed == wanted, (sorted(wanted - listed), sorted(listed - wanted))
