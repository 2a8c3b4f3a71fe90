"""Benchmark of the results store's recompute (``make reproduce``) in one process and on Dask (a script, not a test):
prints a table and writes JSON, so that a reader can size a cluster.

    .venv/bin/python benchmarks/bench_cluster.py [--fraction 0.25] [--only NAME ...] [--workers 1 2]
                                                 [--out benchmarks/bench_cluster.json]

For each set-up (this process; a ``LocalCluster`` of N single-threaded worker processes for each N of --workers),
in a fresh process with an empty Monte Carlo cache and an empty JAX compilation cache: the stored experiments
(``catalog.store_experiments``; ``--only`` names some: by default one of each kind of engine, the honest and the
truth-centred Fig. 9, Fig. 10 centred on OTDoA, Fig. 9 with PRS reuse) at ``--fraction`` of their trial counts
(at least one chunk each), computed with ``engine.run`` as ``dpe5g reproduce`` does.  Reports the wall time, each experiment's time per trial, the peak
resident memory of the process and of each worker, and XLA's threads (``XLA_FLAGS``, the CPUs each process sees).
Every set-up's results are compared with the store (``verify.differences``): the cluster computes the same trials.
``--fraction 1`` is the whole ``make reproduce``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

from benchutil import write

HERE = os.path.dirname(os.path.abspath(__file__))

RUN = """
import json, os, resource, sys, time
import numpy as np
from dpe5g.common import cluster
from dpe5g.simulation import engine, store, verify
from dpe5g.studies import catalog
fraction, workers, only = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3:]
client = cluster.connect(workers=workers) if workers else None
rows, t_all, n_diff = [], time.perf_counter(), 0
for e in [e for e in catalog.store_experiments() if not only or e.run.name in only]:
    n = max(e.run.chunk_trials, int(round(e.run.n_trials * fraction)))
    e = e.replace(n_trials=min(n, e.run.n_trials))
    t0 = time.perf_counter()
    res = engine.run(e, progress=False, use_store=False, client=client)
    dt = time.perf_counter() - t0
    arrays = {k: getattr(res, k) for k in store.stored_fields(e)}
    n_diff += len(verify.differences(e.run.name, range(e.run.n_trials), store.stored(e).load(e.run.n_trials), arrays))
    rows.append({"experiment": e.run.name, "trials": e.run.n_trials, "s": dt, "ms_per_trial": 1e3 * dt / e.run.n_trials})
wall = time.perf_counter() - t_all
mem = [resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024]
if client is not None:
    mem += [v / 2**20 for v in client.run(lambda: __import__("resource").getrusage(
        __import__("resource").RUSAGE_SELF).ru_maxrss * 1024).values()]
    cluster.close(client)
print(json.dumps({"wall_s": wall, "rows": rows, "differences": n_diff, "peak_rss_mb": mem,
                  "xla_flags": os.environ.get("XLA_FLAGS", ""), "cpus": len(os.sched_getaffinity(0))}))
"""


#: one experiment of each kind of engine (``--only``'s default)
DEFAULT_ONLY = ("fig09-honest", "fig09", "fig10-two-of-four-otdoa", "fig09-power-reuse6")


def run_setup(fraction: float, workers: int, only) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "DPE5G_CACHE": os.path.join(tmp, "mc"), "DPE5G_JAX_CACHE": os.path.join(tmp, "jax")}
        out = subprocess.run([sys.executable, "-c", RUN, str(fraction), str(workers), *only], env=env, check=True,
                             capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fraction", type=float, default=0.25, help="share of each experiment's trials (1: all)")
    ap.add_argument("--only", nargs="+", default=list(DEFAULT_ONLY), metavar="NAME",
                    help="stored experiments to run (default: one of each kind of engine); 'all' for every one")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="LocalCluster sizes to time")
    ap.add_argument("--out", default=os.path.join(HERE, "bench_cluster.json"))
    args = ap.parse_args()
    only = [] if args.only == ["all"] else args.only
    setups = {"this process": run_setup(args.fraction, 0, only)}
    for n in args.workers:
        setups[f"LocalCluster, {n} worker{'s' if n > 1 else ''}"] = run_setup(args.fraction, n, only)
    print(f"\nmake reproduce's compute at {args.fraction:g} of the stored trial counts of "
          f"{', '.join(only) or 'every stored experiment'} (empty caches):")
    print(f"{'set-up':28s} {'wall (s)':>9s} {'differences':>12s} {'peak RSS per process (MB)':>28s}")
    for name, r in setups.items():
        print(f"{name:28s} {r['wall_s']:9.1f} {r['differences']:12d} {', '.join(f'{m:.0f}' for m in r['peak_rss_mb']):>28s}")
    base = setups["this process"]["rows"]
    print(f"\ncost per trial, this process (ms; includes the compile):\n{'experiment':42s} {'trials':>6s} {'ms/trial':>9s}")
    for r in base:
        print(f"{r['experiment']:42s} {r['trials']:6d} {r['ms_per_trial']:9.1f}")
    write(args.out, {"fraction": args.fraction, "only": only, "setups": setups})


if __name__ == "__main__":
    main()
