"""The code behind a Monte Carlo result, as a key: the package's modules the engine runs (``source_modules``), each
by its syntax tree without docstrings or comments (``code_digest``), and the numerical libraries' versions
(``numerics``), hashed together by ``code_version``, which ``experiment.Experiment.key`` adds to a config's key.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import sys
from functools import lru_cache
from importlib.metadata import version
from pathlib import Path

import jax

#: the package's folder (``dpe5g/``, two above this module)
PACKAGE = Path(__file__).resolve().parents[1]

#: the module whose imports reach every module the Monte Carlo results depend on: ``source_modules`` follows them
ENGINE_MODULE = "simulation/engine.py"


def code_version(package: Path | None = None) -> str:
    """Hash of the code the Monte Carlo results depend on and of the numerical libraries' versions.

    The code is ``source_modules``, each by ``code_digest``, the versions ``numerics``: what ``Experiment.key`` adds to
    the config.

    Parameters
    ----------
    package : Path or None
        The package's folder; None: this one's.

    Returns
    -------
    str
    """
    here = PACKAGE if package is None else Path(package)
    h = hashlib.sha256(json.dumps(numerics()).encode())
    for name in source_modules(here):
        h.update(name.encode() + b"\0" + code_digest(here / name))
    return h.hexdigest()[:16]


def changed_since_import() -> tuple[str, ...]:
    """The ``source_modules`` whose files changed after this process imported ``dpe5g`` (``dpe5g.IMPORTED_AT_NS``).

    The code it runs is then older than ``code_version`` says (a Dask worker left running across a ``git pull``).

    Returns
    -------
    tuple of str
    """

    imported_at = sys.modules[PACKAGE.name].IMPORTED_AT_NS  # the package's, read now (a test may set it)
    here = PACKAGE
    return tuple(n for n in source_modules() if (here / n).stat().st_mtime_ns > imported_at)


def source_modules(package: Path | None = None) -> tuple[str, ...]:
    """The package's modules a Monte Carlo result depends on, found from the code instead of a list kept by hand.

    Every package's ``__init__.py`` (the top one sets JAX's precision; importing a module runs the ``__init__`` of
    each package above it) and every module ``ENGINE_MODULE`` imports, directly or through others, at the top or
    inside a function, from any depth of the package's folders (``package_imports``).

    Parameters
    ----------
    package : Path or None
        The package's folder; None: this one's.

    Returns
    -------
    tuple of str
        Paths inside the package's folder, "/"-separated ("engine.py", "sub/__init__.py"), sorted.
    """
    here = PACKAGE if package is None else Path(package)
    seen = set()
    todo = [p.relative_to(here).as_posix() for p in sorted(here.rglob("__init__.py"))] + [ENGINE_MODULE]
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo += package_imports(here / name, here)
    return tuple(sorted(seen))


def package_imports(path: Path, package: Path | None = None) -> list[str]:
    """The package's modules that a module imports, anywhere in it.

    Parameters
    ----------
    path : Path
        The module, inside ``package``; its imports ``from . import a``, ``from .a import f``, ``from ..a.b import f``
        (relative imports of any depth, resolved as Python resolves them), ``from dpe5g.a import f``, ``import
        dpe5g.a.b``.
    package : Path or None
        The package's top folder; None: the module's own folder.

    Returns
    -------
    list of str
        Paths inside ``package``, "/"-separated: a module ``a/b.py`` or a package's ``a/__init__.py``.
    """
    path = Path(path).resolve()
    root = path.parent if package is None else Path(package).resolve()
    st = path.stat()
    return list(_package_imports(str(path), str(root), st.st_mtime_ns, st.st_size))


@lru_cache(maxsize=256)
def _package_imports(path: str, root: str, mtime_ns: int, size: int) -> tuple[str, ...]:
    top, rel = Path(root), Path(path).relative_to(root)
    name = top.name
    parts = rel.with_suffix("").parts
    own_package = ".".join((name, *parts[:-1]))  # a module's __package__; an __init__'s is its own folder
    names = []
    for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = importlib.util.resolve_name("." * node.level + (node.module or ""), own_package)
            elif (node.module or "").split(".")[0] == name:
                base = node.module
            else:
                continue
            names += [base] + [f"{base}.{a.name}" for a in node.names]  # from .a import b: b a name or a module
        elif isinstance(node, ast.Import):
            names += [a.name for a in node.names if a.name.split(".")[0] == name]
    found = set()
    for dotted in names:
        inner = dotted.split(".")[1:]
        for candidate in (top.joinpath(*inner).with_suffix(".py") if inner else None,
                          top.joinpath(*inner, "__init__.py")):
            if candidate is not None and candidate.is_file():
                found.add(candidate.relative_to(top).as_posix())
    return tuple(sorted(found))


def code_digest(path: Path) -> bytes:
    """A module's code for the cache key: its syntax tree without docstrings, comments or line numbers.

    Editing the prose of a module does not invalidate cached results, while any change of code does.  Remembered per
    file version (path, modification time and size: an edited file is parsed again), as parsing costs about 40 ms and
    every key reads every module.

    Parameters
    ----------
    path : Path
        The module.

    Returns
    -------
    bytes
    """
    st = Path(path).stat()
    return _code_digest(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=64)
def _code_digest(path: str, mtime_ns: int, size: int) -> bytes:
    tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def numerics() -> dict:
    """What else the numbers depend on: {library: version, "x64": JAX's float precision}, the OTDoA solver's too.

    Returns
    -------
    dict
    """
    return {**_library_versions(), "x64": bool(jax.config.jax_enable_x64)}


@lru_cache(maxsize=1)
def _library_versions() -> dict:
    """{library: installed version}, read once per process (the metadata lookups cost 5 ms a key)."""
    return {lib: version(lib) for lib in ("jax", "jaxlib", "numpy", "cvxpy", "clarabel")}
