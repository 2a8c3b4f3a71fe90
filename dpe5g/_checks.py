"""Input validation shared by the modules.

Every public function that takes user input checks it here and raises a ``ValueError`` that names the
parameter, the value received and the allowed range, so that the CLI can print one line and exit 2.
"""

from __future__ import annotations

import math
from typing import Iterable


def finite(name: str, value: float) -> float:
    """Return ``float(value)`` or raise if it is NaN or infinite."""
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
    if isinstance(value, bool) or int(value) != value:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    v = int(value)
    if not lo <= v <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def one_of(name: str, value: str, allowed: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise listing them."""
    allowed = list(allowed)
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(str, allowed))}; got {value!r}")
    return value
