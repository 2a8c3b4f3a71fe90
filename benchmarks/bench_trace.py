"""Benchmark of the ray tracing of a city in chunks (``city.trace_chunks``) in this process and on Dask workers (a
script, not a test): prints a table and writes JSON, so that a reader can size a cluster for a larger city or a
denser network.

    .venv/bin/python benchmarks/bench_trace.py [--ues 100] [--batch 25] [--workers 1 2] [--gpu]
                                               [--out benchmarks/bench_trace.json]

The book's city settings (``city.trace.CitySpec()``: Munich, 26 BSs, diffuse reflection on) with ``--ues`` UEs traced
in batches of ``--batch`` (the stored city's calls hold ``trace.ues_per_call`` = 50 UEs; a smaller batch keeps two
workers inside this machine's memory), each set-up from an empty trace cache: in this process on Dr.Jit's pool of
threads (``trace.trace_links``, as the stored city was traced), in this process on one thread
(``trace_chunks.trace_city``, the same bits at every run), and on a ``LocalCluster`` of N worker processes for each
N of ``--workers`` (one batch per task; each worker loads the scene itself), each set-up in a fresh process (a
process keeps what Dr.Jit allocated: three of them at once ran this machine out of memory).  Reports the wall time of the links
(the scene's loading and the placements timed apart, once), links per second, and whether every set-up's city is
the same bits as the one-thread run's.  With ``--gpu``, also in this process on Dr.Jit's CUDA backend
(``ray_tracer.use_backend("cuda")``; every other set-up on the CPU, ``"llvm"``), compared with the one-thread CPU run
link by link (``against_cpu``: the links only one traced, and a link's power and first-path delay against the store's
per-link re-trace tolerances ``dataset.VERIFY_POWER_DB`` and ``dataset.VERIFY_EXCESS_S``); where Dr.Jit finds no GPU,
that row says so and is not measured.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchutil import write

SETUPS = {"threads": "this process, Dr.Jit's threads", "one": "this process, one thread",
          "cuda": "this process, Dr.Jit's CUDA backend"}


def against_cpu(gpu: dict, cpu: dict) -> dict:
    """The GPU's links against the CPU's: the links traced by one only, and on the links both traced the largest
    difference of a link's power (dB) and of its first path's delay (s), each against the per-link tolerance of the
    store's re-trace (``dataset.compare_links`` also compares first-path gains and a median; not here).  "within":
    no link traced by one only, and both differences within their tolerance."""
    from dpe5g.city import dataset

    key = lambda d: {(int(u), int(b)): i for i, (u, b) in enumerate(zip(d["link_ue"], d["link_bs"]))}  # noqa: E731
    kg, kc = key(gpu), key(cpu)
    both = sorted(set(kg) & set(kc))
    ig, ic = [kg[k] for k in both], [kc[k] for k in both]
    d_power = float(np.max(np.abs(gpu["power_db"][ig] - cpu["power_db"][ic]), initial=0.0))
    d_first = float(np.max(np.abs(gpu["excess_s"][ig, 0] - cpu["excess_s"][ic, 0]), initial=0.0))
    return {"links_both": len(both), "gpu_only": len(set(kg) - set(kc)), "cpu_only": len(set(kc) - set(kg)),
            "max_power_db": d_power, "max_first_excess_s": d_first,
            "within": (set(kg) == set(kc) and d_power <= dataset.VERIFY_POWER_DB
                       and d_first <= dataset.VERIFY_EXCESS_S),
            "tolerance": {"power_db": dataset.VERIFY_POWER_DB, "first_excess_s": dataset.VERIFY_EXCESS_S}}


def run_setup(setup: str, ues: int, batch: int, folder: str) -> dict:
    """One set-up in this process: its arrays saved to ``folder``/``setup``.npz, its times returned."""
    from dpe5g.city import trace, trace_chunks
    from dpe5g.common import cluster

    from dpe5g.city import ray_tracer
    from dpe5g.common.errors import Failure

    spec = trace.CitySpec(n_ue=ues)
    try:  # (every set-up but "cuda" on the CPU, also on a machine with a GPU)
        ray_tracer.use_backend("cuda" if setup == "cuda" else "llvm")
    except Failure as err:
        return {"error": str(err)}
    t0 = time.perf_counter()
    scene, region, bs, ue = trace.layout(spec)
    layout_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    if setup == "threads":
        got = trace.trace_links(scene, bs, ue, spec, batch=batch)
    else:
        del scene
        client = None if setup in ("one", "cuda") else cluster.connect(workers=int(setup))
        try:
            got = trace_chunks.trace_city(spec, progress=False, cache=f"{folder}/cache-{setup}", batch=batch,
                                          client=client)
        finally:
            cluster.close(client)
        got = {k: v for k, v in got.items() if k not in ("region", "bs_xyz", "ue_xyz")}
    seconds = time.perf_counter() - t0 - (0.0 if setup == "threads" else layout_s)  # (trace_city places them again)
    np.savez(f"{folder}/{setup}.npz", **got)
    return {"seconds": seconds, "layout_s": layout_s, "links": int(len(got["link_ue"])), "bs": int(len(bs)),
            "scene": spec.scene}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ues", type=int, default=100)
    ap.add_argument("--batch", type=int, default=25)
    ap.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--gpu", action="store_true", help="also trace on Dr.Jit's CUDA backend, compared with the CPU")
    ap.add_argument("--out", default="benchmarks/bench_trace.json")
    ap.add_argument("--setup", default=None, help=argparse.SUPPRESS)  # (a child: one set-up)
    ap.add_argument("--folder", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.setup is not None:
        print(json.dumps(run_setup(a.setup, a.ues, a.batch, a.folder)))
        return
    rows, gpu = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for setup in ["threads", "one", *map(str, a.workers), *(["cuda"] if a.gpu else [])]:
            r = subprocess.run([sys.executable, os.path.abspath(__file__), "--setup", setup, "--folder", tmp,
                                "--ues", str(a.ues), "--batch", str(a.batch)], capture_output=True, text=True,
                               check=True)
            out = json.loads(r.stdout.strip().splitlines()[-1])
            if "error" in out:
                gpu = {"measured": False, "why": out["error"]}
                print(f"CUDA backend: not measured ({out['error']})", flush=True)
                continue
            name = SETUPS.get(setup, f"{setup} Dask worker{'s' if setup != '1' else ''} (one thread each)")
            rows.append((setup, name, out))
            print(f"{name}: {out['seconds']:.1f} s, {out['links']} links", flush=True)
        one = dict(np.load(f"{tmp}/one.npz"))
        same = {s: all(np.array_equal(np.load(f"{tmp}/{s}.npz")[k], one[k]) for k in one) for s, _, _ in rows}
        if any(s == "cuda" for s, _, _ in rows):
            gpu = {"measured": True, **against_cpu(dict(np.load(f"{tmp}/cuda.npz")), one)}
            print(f"CUDA against the CPU: {gpu}", flush=True)
    first = rows[0][2]
    print(f"{a.ues} UEs x {first['bs']} BSs of {first['scene']}, batches of {a.batch} UEs; scene and placements "
          f"{first['layout_s']:.1f} s (not counted below)")
    print(f"{'set-up':40s} {'seconds':>8s} {'links':>6s} {'links/s':>8s}  same bits as one thread")
    for s, name, r in rows:
        print(f"{name:40s} {r['seconds']:8.1f} {r['links']:6d} {r['links'] / r['seconds']:8.2f}  {same[s]}")
    write(a.out, {"ues": a.ues, "bs": first["bs"], "batch": a.batch, "scene": first["scene"],
                  "layout_s": round(first["layout_s"], 1),
                  "rows": [{"setup": name, "seconds": round(r["seconds"], 1), "links": r["links"],
                            "links_per_s": round(r["links"] / r["seconds"], 2), "same_bits_as_one_thread": same[s]}
                           for s, name, r in rows], "cuda": gpu})


if __name__ == "__main__":
    main()
