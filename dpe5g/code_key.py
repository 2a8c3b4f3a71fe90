"""The code behind a Monte Carlo result, as a key: the package's modules the engine runs (``source_modules``), each
by its syntax tree without docstrings or comments (``code_digest``), and the numerical libraries' versions
(``numerics``), hashed together by ``code_version``, which ``experiment.Experiment.key`` adds to a config's key.
"""

from __future__ import annotations

import ast
import hashlib
import json
from functools import lru_cache
from pathlib import Path

import jax

#: the module whose imports reach every module the Monte Carlo results depend on: ``source_modules`` follows them
ENGINE_MODULE = "engine.py"


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
    here = Path(__file__).resolve().parent if package is None else Path(package)
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
    from . import IMPORTED_AT_NS

    here = Path(__file__).resolve().parent
    return tuple(n for n in source_modules() if (here / n).stat().st_mtime_ns > IMPORTED_AT_NS)


def source_modules(package: Path | None = None) -> tuple[str, ...]:
    """The package's modules a Monte Carlo result depends on, found from the code instead of a list kept by hand.

    ``__init__.py`` (it sets JAX's precision) and every module ``ENGINE_MODULE`` imports, directly or through others, at
    the top or inside a function (``package_imports``).

    Parameters
    ----------
    package : Path or None
        The package's folder; None: this one's.

    Returns
    -------
    tuple of str
        File names, sorted.
    """
    here = Path(__file__).resolve().parent if package is None else Path(package)
    seen, todo = {"__init__.py"}, [ENGINE_MODULE]
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo += package_imports(here / name)
    return tuple(sorted(seen))


def package_imports(path: Path) -> list[str]:
    """The file names of the package's modules that a module imports, anywhere in it.

    Parameters
    ----------
    path : Path
        The module; its imports ``from . import a``, ``from .a import f``, ``from dpe5g.a import f``, ``import
        dpe5g.a``.

    Returns
    -------
    list of str
    """
    st = Path(path).stat()
    return list(_package_imports(str(Path(path).resolve()), st.st_mtime_ns, st.st_size))


@lru_cache(maxsize=128)
def _package_imports(path: str, mtime_ns: int, size: int) -> tuple[str, ...]:
    here = Path(path).parent
    found = []
    for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 1:  # from . import a / from .a import f
            found += [node.module.split(".")[0]] if node.module else [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "dpe5g":
            parts = node.module.split(".")
            found += parts[1:2] if len(parts) > 1 else [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            found += [a.name.split(".")[1] for a in node.names if a.name.startswith("dpe5g.")]
    return tuple(sorted({f"{n}.py" for n in found if (here / f"{n}.py").is_file()}))


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
    from importlib.metadata import version

    return {lib: version(lib) for lib in ("jax", "jaxlib", "numpy", "cvxpy", "clarabel")}
