"""What the benchmark scripts share: the timing rule, the machine's description and the JSON output."""

from __future__ import annotations

import json
import os
import platform
import time

import jax
import numpy as np


def median_time(fn, repeats: int) -> float:
    """Median wall-clock seconds of ``fn()`` over ``repeats`` runs, after one warm-up call (compile)."""
    jax.block_until_ready(fn())
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def machine() -> dict:
    return {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
            "device": str(jax.devices()[0])}


def write(path: str, result: dict) -> None:
    """Write ``result`` with the machine's description first, and say where."""
    with open(path, "w") as f:
        json.dump({"machine": machine(), **result}, f, indent=1)
    print(f"wrote {path}")
