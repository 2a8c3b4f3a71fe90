"""Benchmark of the NLoS-aware OTDoA receiver against today's (a script, not a test): prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_otdoa_nlos.py [--out benchmarks/bench_otdoa_nlos.json]

1. One fix from given ToAs: ``otdoa.Solver.solve`` (the SOCP and its polish, the paper's baseline) against
   ``otdoa_nlos.NlosSolver.fix`` (the weighted SOCP and polish, residual test, exclusions), for M = 4, 6 and 12 links,
   every ToA unbiased and with one link 30 m late (where M ≥ 5, the exclusion's leave-one-out fits run);
2. the per-link detection from the received signals: ``otdoa.toa`` (first path) against ``otdoa_nlos.link_sigma_m``
   (both detectors and the correlogram's SNR), M = 6, N = 4096.
Times are medians of repeated runs (wall clock, after a warm-up call), on the same random geometries for both.
"""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np

from benchutil import median_time, write

from dpe5g.phy import nr, signal
from dpe5g.receivers import cost, otdoa, otdoa_nlos
from dpe5g.phy.nr import C

HERE = os.path.dirname(os.path.abspath(__file__))


def geometry(m: int, seed: int):
    """m BSs 100–400 m around a UE at the origin (2 m high), their ToAs with 1 m noise, and the same with link 1
    30 m late."""
    rng = np.random.default_rng(seed)
    ang, r = np.sort(rng.uniform(0, 2 * np.pi, m)), rng.uniform(100, 400, m)
    b = np.stack([r * np.cos(ang), r * np.sin(ang), np.full(m, 10.0)], -1)
    rng_m = np.linalg.norm(np.array([0.0, 0.0, 2.0]) - b, axis=1) + rng.normal(0, 1.0, m)
    late = rng_m.copy()
    late[1] += 30.0
    return b, rng_m / C, late / C


def fix_times(repeats: int) -> list[dict]:
    rows = []
    for m in (4, 6, 12):
        b, clean, late = geometry(m, m)
        base, nlos = otdoa.Solver(m), otdoa_nlos.NlosSolver()
        sig = np.ones(m)
        for case, t in (("unbiased", clean), ("one link 30 m late", late)):
            t_base = median_time(lambda: base.solve(b, t, 2.0).xyz, repeats)
            t_nlos = median_time(lambda: nlos.fix(b, t, sig, 2.0).xyz, repeats)
            f = nlos.fix(b, t, sig, 2.0)
            rows.append({"m": m, "case": case, "otdoa_ms": 1e3 * t_base, "otdoa_nlos_ms": 1e3 * t_nlos,
                         "ratio": t_nlos / t_base, "excluded": list(f.excluded), "detected": f.detected})
    return rows


def detection_times(repeats: int) -> dict:
    m = 6
    b, _, _ = geometry(m, 0)
    prs = nr.prs_matrix(range(m))
    tau = np.asarray(cost.toa(np.array([0.0, 0.0, 2.0]), b, 0.0))
    y = signal.received_samples(jax.random.PRNGKey(0), prs, np.ones((m, 1)), np.zeros((m, 1)), tau, 0.0)
    t_toa = median_time(lambda: otdoa.toa(y, prs), repeats)
    t_sig = median_time(lambda: otdoa_nlos.link_sigma_m(y, prs)[1], repeats)
    return {"m": m, "n_fft": int(prs.shape[1]), "toa_ms": 1e3 * t_toa, "link_sigma_ms": 1e3 * t_sig,
            "ratio": t_sig / t_toa}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(HERE, "bench_otdoa_nlos.json"))
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    rows, det = fix_times(args.repeats), detection_times(args.repeats)
    print(f"{'M':>3} {'case':<20} {'otdoa (ms)':>11} {'NLoS-aware (ms)':>16} {'ratio':>6}  excluded")
    for r in rows:
        print(f"{r['m']:>3} {r['case']:<20} {r['otdoa_ms']:>11.2f} {r['otdoa_nlos_ms']:>16.2f} {r['ratio']:>6.1f}  "
              f"{r['excluded'] if r['excluded'] else ('none, detected' if r['detected'] else 'none')}")
    print(f"per-link detection, M = {det['m']}, N = {det['n_fft']}: otdoa.toa {det['toa_ms']:.2f} ms, "
          f"link_sigma_m {det['link_sigma_ms']:.2f} ms ({det['ratio']:.1f}x)")
    write(args.out, {"fix": rows, "detection": det, "repeats": args.repeats})


if __name__ == "__main__":
    main()
