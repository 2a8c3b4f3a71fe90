"""Benchmark of the figure build (a script, not a test): every registered figure from empty caches; prints a table
and writes JSON.

    .venv/bin/python benchmarks/bench_figures.py [--out benchmarks/bench_figures.json]

Runs ``dpe5g figures --out <temporary folder>`` — what ``make reproduce`` does after recomputing the results store,
without writing the committed baselines — in a fresh process with an empty Monte Carlo cache (``DPE5G_CACHE``) and
an empty JAX compilation cache (``DPE5G_JAX_CACHE``), as on a fresh clone, the Monte Carlo read from the committed
results store (``DPE5G_STORE=off`` in the environment computes it instead, the whole of the old ``make figures``),
and records its wall-clock and CPU seconds and each
figure's seconds as the command prints them (figures run in the registry's order, so a figure whose experiments an
earlier one computed reads them from the cache).  Target (issue 11): ≤ 240 s.  The figures' own numbers are not
compared here; the figure-diff (``tests/book/test_figures.py``) does that.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time

from benchutil import write

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
TARGET_S = 240.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(HERE, "bench_figures.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, DPE5G_CACHE=os.path.join(tmp, "montecarlo"), DPE5G_JAX_CACHE=os.path.join(tmp, "jax"))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "dpe5g", "figures", "--out", os.path.join(tmp, "figures")],
                              cwd=ROOT, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout + proc.stderr)
        raise SystemExit(f"dpe5g figures failed with exit code {proc.returncode}")
    per_figure = {m.group(1): float(m.group(2))
                  for m in re.finditer(r"^(\S+): \S+ \S+ \(([0-9.]+) s\)$", proc.stdout, flags=re.M)}
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(f"{'figure':<32} {'seconds':>8}")
    for fig_id, s in per_figure.items():
        print(f"{fig_id:<32} {s:8.1f}")
    print(f"{'all figures, wall (target <= 240 s)':<32} {wall:8.1f}")
    print(f"{'all figures, CPU':<32} {cpu:8.1f}")
    write(args.out, {"wall_s": wall, "cpu_s": cpu, "target_s": TARGET_S, "per_figure_s": per_figure})


if __name__ == "__main__":
    main()
