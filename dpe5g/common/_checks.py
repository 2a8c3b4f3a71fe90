"""Input validation shared by the modules.

Every public function that takes user input checks it here and raises a ``ValueError`` that names the
parameter, the value received and the allowed range, so that the CLI can print one line and exit 2.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Iterable

import jax
import numpy as np


def finite(name: str, value: float) -> float:
    """Return ``float(value)`` or raise if it is NaN or infinite, or not a number (a text, True/False)."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def in_range(name: str, value: float, lo: float, hi: float, unit: str = "") -> float:
    """Return ``float(value)`` if ``lo <= value <= hi``, else raise naming the range."""
    v = finite(name, value)
    if not lo <= v <= hi:
        u = f" {unit}" if unit else ""
        raise ValueError(f"{name} must be in [{lo:g}, {hi:g}]{u}, got {value!r}")
    return v


def integer(name: str, value: int, lo: int, hi: int) -> int:
    """Return ``int(value)`` if it is an integer in ``[lo, hi]``, else raise."""
    try:
        whole = not isinstance(value, (bool, str, bytes)) and int(value) == value
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    v = int(value)
    if not lo <= v <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def values_in_range(name: str, value, lo: float, hi: float, unit: str = ""):
    """Check an array (or scalar) of a physical quantity: real, finite and in [lo, hi] ``unit``; returns it as
    given.  Inside a traced (jit, vmap) call it is a JAX tracer, whose values are not known: returned unchecked
    (the engine checks its inputs before tracing)."""
    if isinstance(value, jax.core.Tracer):
        return value
    try:
        a = np.asarray(value)
        if isinstance(value, (list, tuple)) and any(isinstance(x, (bool, np.bool_, str, bytes))
                                                    for x in np.asarray(value, dtype=object).ravel()):
            a = np.asarray(None)  # True/False or a text among numbers, which NumPy would have made 1.0, 0.0
    except (TypeError, ValueError):  # a ragged nest of lists
        a = np.asarray(None)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be real numbers in [{lo:g}, {hi:g}] {unit}, got {value!r:.60}")
    bad = ~np.isfinite(a) | (a < lo) | (a > hi)
    if np.any(bad):
        first = a[bad].ravel()[0] if a.ndim else a
        raise ValueError(f"{name} must be finite and in [{lo:g}, {hi:g}] {unit}, got {first!r}")
    return value


def one_of(name: str, value: str, allowed: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise listing them."""
    allowed = list(allowed)
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(str, allowed))}; got {value!r}")
    return value


#: a name of something the results store keeps (an experiment's runs, a traced city): it becomes part of a file name
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")


def name(param: str, value) -> str:
    """Check that ``value`` is a name, never a path: 1–100 letters, digits, ".", "_" or "-", starting with a letter or
    digit, without "..".

    Parameters
    ----------
    param : str
        The parameter's name, for the message.
    value : str
        The name.

    Returns
    -------
    str
        ``value``.

    Raises
    ------
    ValueError
        Naming ``param``, the allowed form and ``value``.
    """
    if not isinstance(value, str) or not NAME.fullmatch(value) or ".." in value:
        raise ValueError(f"{param} must be a name of 1-100 letters, digits, '.', '_' or '-' that starts with a letter "
                         f"or digit (it names files in the results store, never a path), got {value!r}")
    return value


def require_x64() -> None:
    """Raise unless JAX float64 is on.

    ``import dpe5g`` turns it on; this guards the computing entry points against it having been turned off since
    (``jax.config.update("jax_enable_x64", False)``, ``jax.experimental.disable_x64``), which would silently move
    ToAs by centimetres (float32 carries ~7 digits of a ~1e-6 s ToA) and change every DPE result.  Called at trace
    time inside jitted functions, so the check costs nothing per call."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError("dpe5g needs JAX float64 (jax_enable_x64), which is off: ToAs and phases lose their "
                           "precision in float32.  `import dpe5g` turns it on; do not turn it off afterwards.")


def plain(value):
    """``value`` as the plain Python a config holds: a NumPy scalar as its Python number (``np.float64(10)`` → 10.0,
    ``np.int64(6)`` → 6, ``np.bool_`` → bool), a list, tuple or array as a tuple of plain values; anything else as
    it is.  So settings given as lists or NumPy values hash (``Experiment.config_key``) as the same plain numbers."""
    if isinstance(value, np.generic) or (isinstance(value, np.ndarray) and value.ndim == 0):
        return value.item()
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(plain(v) for v in value)
    return value


def as_declared(value, declared: str):
    """A plain value (``plain``) as the type its field declares, so that equal settings hash alike: an int (not a
    bool) where ``float`` is declared as a float (5 → 5.0), a whole float where ``int`` is declared as an int
    (9.0 → 9), and so element-wise for ``tuple[float, ...]`` and ``tuple[int, ...]``; anything else as it is (the
    field's own check then judges it)."""
    if declared == "float" and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if declared == "int" and isinstance(value, float) and value.is_integer():
        return int(value)
    if declared in ("tuple[float, ...]", "tuple[int, ...]") and isinstance(value, tuple):
        return tuple(as_declared(v, declared[6:-6]) for v in value)
    return value


def plain_fields(obj) -> None:
    """Replace each field of the frozen dataclass ``obj`` by its ``plain`` value as its declared type
    (``as_declared``; in ``__post_init__``), so settings given as lists, NumPy values or ints where floats are
    declared give the same object and the same key as the plain numbers; a ``bool`` field takes only True or False
    (or a NumPy bool)."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        declared = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        p = as_declared(plain(v), declared)
        if declared == "bool" and not isinstance(p, bool):  # not "False" (truthy) and not 1 (another key)
            raise ValueError(f"{f.name} must be True or False, got {v!r}")
        if declared.startswith("tuple[") and not isinstance(p, tuple):
            raise ValueError(f"{f.name} must be a tuple (or list) of values, got {v!r}")
        if p is not v:
            object.__setattr__(obj, f.name, p)
