"""The XLA backend optimisation level that importing dpe5g asks for (``dpe5g.XLA_OPT_LEVEL``) changes no result: the
engines run in a process at XLA's own default level give the same bits as in this one."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import dpe5g
from dpe5g import engine, experiment, results, search_config

SMALL = dict(n_trials=4, seed=3, snrs_db=(15.0, 30.0), m_values=(4, 6))
#: a truth-centred grid search, the certified search on a prior, and the certified search on the OTDoA fixes
EXPERIMENTS = {
    "grid": dict(name="xla-grid", search=dict(half_width_m=3.0, bias_half_width_m=3.0)),
    "bnb": dict(name="xla-bnb", centring="prior", prior_kind="gaussian", prior_scale_m=1.0,
                search=dict(method="bnb", half_width_m=3.0)),
    "otdoa": dict(name="xla-otdoa", centring="otdoa", otdoa=True, search=dict(method="bnb", half_width_m=3.0)),
}
SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from dpe5g import engine, experiment, search_config
    from tests.test_xla_level import EXPERIMENTS, SMALL, fields
    out = {}
    for k, kw in EXPERIMENTS.items():
        e = experiment.Experiment.build(**SMALL, **{**kw, "search": search_config.SearchConfig(**kw["search"])})
        r = engine.run(e, cache=sys.argv[1], progress=False)
        out.update({f"{k}/{f}": getattr(r, f) for f in fields(e)})
    np.savez(sys.argv[2], **out)
""")


def fields(e):
    return results.Results.FIELDS + (results.Results.OTDOA_FIELDS if e.receiver.otdoa else ())


def test_the_flag_is_added_unless_set():
    assert dpe5g.xla_flags("", None) == f"--xla_backend_optimization_level={dpe5g.XLA_OPT_LEVEL}"
    assert dpe5g.xla_flags("--xla_foo=1", "3") == "--xla_foo=1 --xla_backend_optimization_level=3"
    assert dpe5g.xla_flags("--xla_backend_optimization_level=2", "1") == "--xla_backend_optimization_level=2"
    assert dpe5g.xla_flags("--xla_foo=1", "xla") == "--xla_foo=1"
    with pytest.raises(ValueError, match="DPE5G_XLA_OPT_LEVEL must be one of 0, 1, 2, 3 or xla, got '7'"):
        dpe5g.xla_flags("", "7")


def test_results_are_the_same_bits_at_xlas_default_level(tmp_path):
    mine = f"--xla_backend_optimization_level={dpe5g.XLA_OPT_LEVEL}"
    if mine not in os.environ.get("XLA_FLAGS", ""):
        pytest.skip("the environment sets the level")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "XLA_FLAGS": os.environ["XLA_FLAGS"].replace(mine, "").strip(), "DPE5G_XLA_OPT_LEVEL": "xla",
        "PYTHONPATH": root}
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "default"), str(tmp_path / "default.npz")],
                       capture_output=True, text=True, timeout=600, env=env, cwd=root)
    assert r.returncode == 0, r.stderr
    theirs = np.load(tmp_path / "default.npz")
    for k, kw in EXPERIMENTS.items():
        e = experiment.Experiment.build(**SMALL, **{**kw, "search": search_config.SearchConfig(**kw["search"])})
        ours = engine.run(e, cache=tmp_path / "ours", progress=False)
        for f in fields(e):
            np.testing.assert_array_equal(getattr(ours, f), theirs[f"{k}/{f}"], err_msg=f"{k}/{f}")
