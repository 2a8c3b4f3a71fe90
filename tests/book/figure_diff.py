"""The figure-diff's comparator of two figure payloads (``tests/book/test_figures.py``)."""

import math

import numpy as np


def compare_data(expected, actual, rtol: float, atol: float, path: str = "") -> tuple[bool, str, float]:
    """Compare two payloads: numbers with |a - e| <= atol + rtol |e|, everything else exactly.

    Returns (ok, where, largest_abs_difference) with ``where`` the JSON path of the first mismatch or of the
    largest numeric difference.
    """
    worst = (0.0, path)
    if isinstance(expected, dict) and isinstance(actual, dict):
        if set(expected) != set(actual):
            return False, f"{path} keys differ: {sorted(set(expected) ^ set(actual))}", math.inf
        for k in sorted(expected):
            ok, where, diff = compare_data(expected[k], actual[k], rtol, atol, f"{path}.{k}")
            if not ok:
                return ok, where, diff
            worst = max(worst, (diff, where))
        return True, worst[1], worst[0]
    if isinstance(expected, list) and isinstance(actual, list):
        if len(expected) != len(actual):
            return False, f"{path} length {len(expected)} != {len(actual)}", math.inf
        if expected and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in expected + actual):
            e = np.asarray(expected, dtype=float)
            a = np.asarray(actual, dtype=float)
            diff = np.abs(a - e)
            bad = diff > atol + rtol * np.abs(e)
            i = int(np.argmax(diff)) if diff.size else 0
            if bad.any():
                j = int(np.argmax(bad))
                return False, f"{path}[{j}] expected {e[j]!r} got {a[j]!r}", float(diff.max())
            return True, f"{path}[{i}]", float(diff.max()) if diff.size else 0.0
        for i, (e, a) in enumerate(zip(expected, actual)):
            ok, where, diff = compare_data(e, a, rtol, atol, f"{path}[{i}]")
            if not ok:
                return ok, where, diff
            worst = max(worst, (diff, where))
        return True, worst[1], worst[0]
    if isinstance(expected, (int, float)) and isinstance(actual, (int, float)) and not isinstance(expected, bool):
        diff = abs(float(actual) - float(expected))
        if diff > atol + rtol * abs(float(expected)):
            return False, f"{path} expected {expected!r} got {actual!r}", diff
        return True, path, diff
    if expected != actual:
        return False, f"{path} expected {expected!r} got {actual!r}", math.inf
    return True, path, 0.0
