"""Benchmark of the XLA backend optimisation level that importing dpe5g asks for (``dpe5g.XLA_OPT_LEVEL``; a script,
not a test): prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_xla_level.py [--out benchmarks/bench_xla_level.json]

Three small engines (a truth-centred grid search, the certified search on a prior, the certified search on the OTDoA
fixes; 4 trials, 2 SNRs, M = 4 and 6) are run from empty caches, each in a fresh process, once at dpe5g's level and
once at XLA's own default.  Reports each process's wall time (mostly compiles) and checks that every result field is
the same bits at both levels, so the level is left out of a cached run's key.  Exit 1 if any field differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import textwrap
import time

import numpy as np

from benchutil import write

import dpe5g

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from dpe5g import engine, experiment, results
    from dpe5g.receivers import search_config
    SMALL = dict(n_trials=4, seed=3, snrs_db=(15.0, 30.0), m_values=(4, 6))
    EXPERIMENTS = {
        "grid": dict(name="xla-grid", search=dict(half_width_m=3.0, bias_half_width_m=3.0)),
        "bnb": dict(name="xla-bnb", centring="prior", prior_kind="gaussian", prior_scale_m=1.0,
                    search=dict(method="bnb", half_width_m=3.0)),
        "otdoa": dict(name="xla-otdoa", centring="otdoa", otdoa=True, search=dict(method="bnb", half_width_m=3.0)),
    }
    out = {}
    for k, kw in EXPERIMENTS.items():
        e = experiment.Experiment.build(**SMALL, **{**kw, "search": search_config.SearchConfig(**kw["search"])})
        r = engine.run(e, cache=sys.argv[1], progress=False, use_store=False)
        fields = results.Results.FIELDS + (results.Results.OTDOA_FIELDS if e.receiver.otdoa else ())
        out.update({f"{k}/{f}": getattr(r, f) for f in fields})
    np.savez(sys.argv[2], **out)
""")


def run_at(level: str, tmp: str) -> tuple[float, dict]:
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if "xla_backend_optimization_level" not in f)
    env = {**os.environ, "XLA_FLAGS": flags, "DPE5G_XLA_OPT_LEVEL": level,
           "DPE5G_JAX_CACHE": os.path.join(tmp, f"jax-{level}")}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", SCRIPT, os.path.join(tmp, f"mc-{level}"), os.path.join(tmp, f"{level}.npz")],
                   check=True, env=env, cwd=ROOT)
    return time.perf_counter() - t0, dict(np.load(os.path.join(tmp, f"{level}.npz")))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=os.path.join(HERE, "bench_xla_level.json"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ours_s, ours = run_at(str(dpe5g.XLA_OPT_LEVEL), tmp)
        xla_s, xla = run_at("xla", tmp)
    differ = sorted(k for k in ours if not np.array_equal(ours[k], xla[k], equal_nan=ours[k].dtype.kind == "f"))
    print(f"{'level':28s} {'wall (s), 3 engines from empty caches':>40s}")
    print(f"{'dpe5g (' + str(dpe5g.XLA_OPT_LEVEL) + ')':28s} {ours_s:40.1f}")
    print(f"{'XLA default':28s} {xla_s:40.1f}")
    print(f"fields that differ: {differ or 'none'} (of {len(ours)})")
    write(args.out, {"level": dpe5g.XLA_OPT_LEVEL, "wall_s": {"dpe5g": ours_s, "xla_default": xla_s},
                     "fields": len(ours), "differ": differ})
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
