"""Benchmark of the NLoS-aware DPE against today's honest DPE (a script, not a test): prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_dpe_nlos.py [--out benchmarks/bench_dpe_nlos.json]

One certified fix in the window of Fig. 10's honest receiver under the UMi delay (the 4 nearest BSs, ±30 m, the
"clock_nlos" clock window), on the signals of the first trials of ``nlos_study.fig10_clock_nlos``'s paper's case,
each centred on the truth plus a 6 m offset: the window of the spline correlograms (``spline_bounds.spline_window``
against ``dpe_nlos.marginal_window``, eq. (D1)), then the certified search on it.  Times are medians over the trials
of repeated runs (wall clock, jitted, after a warm-up call), the same trials for both.
"""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

from benchutil import median_time, write

from dpe5g.receivers import certified_search, correlogram, dpe_nlos, receiver, spline_boxes
from dpe5g.simulation import experiment, trials
from dpe5g.studies import nlos as nlos_study

HERE = os.path.dirname(os.path.abspath(__file__))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(HERE, "bench_dpe_nlos.json"))
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    e = nlos_study.fig10_clock_nlos()["two_of_four"]
    cfg, sc = e.receiver_search(), e.scenario
    window = jnp.asarray(receiver.receiver_window(cfg, sc.prs_reuse))
    windows = {"naive (eq. (10))": jax.jit(lambda c, b, x: spline_boxes.spline_window(c, b, x, cfg)),
               "NLoS-aware (eq. (D1))": jax.jit(lambda c, b, x: dpe_nlos.marginal_window(
                   c, b, x, cfg, window, sc.nlos_excess_median_s, sc.nlos_excess_sigma_lg,
                   dpe_nlos.CLOCK_NLOS_QUANTILE))}
    search = jax.jit(lambda sl, st, b, x: certified_search.certified_search((sl, st), b, x, cfg)[0])
    times = {k: {"window_ms": [], "search_ms": []} for k in windows}
    for t in range(args.trials):
        ex = trials.example(e, t)
        coef = correlogram.spline_correlogram(ex.y, ex.prs, cfg.n_taps, cfg.spline_upsample)
        b, x = jnp.asarray(ex.bs_xyz), jnp.asarray([*(ex.ue_xyz[:2] + 6.0), ex.ue_xyz[2], 0.0])
        for k, fn in windows.items():
            sl, st = fn(coef, b, x)
            times[k]["window_ms"].append(1e3 * median_time(lambda: fn(coef, b, x)[0].block_until_ready(),
                                                           args.repeats))
            times[k]["search_ms"].append(1e3 * median_time(lambda: search(sl, st, b, x).q.block_until_ready(),
                                                           args.repeats))
    rows = [{"receiver": k, "window_ms": float(np.median(v["window_ms"])),
             "search_ms": float(np.median(v["search_ms"]))} for k, v in times.items()]
    print(f"{'receiver':<24} {'window (ms)':>12} {'search (ms)':>12} {'fix (ms)':>10}")
    for r in rows:
        print(f"{r['receiver']:<24} {r['window_ms']:>12.2f} {r['search_ms']:>12.2f} "
              f"{r['window_ms'] + r['search_ms']:>10.2f}")
    print(f"NLoS-aware / naive, whole fix: {(rows[1]['window_ms'] + rows[1]['search_ms']) / (rows[0]['window_ms'] + rows[0]['search_ms']):.2f}")
    write(args.out, {"rows": rows, "trials": args.trials, "repeats": args.repeats,
                     "window": {"half_width_m": cfg.half_width_m, "bias_half_width_m": cfg.bias_half_width_m}})


if __name__ == "__main__":
    main()
