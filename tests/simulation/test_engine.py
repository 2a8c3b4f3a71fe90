"""The Monte Carlo engine's runs: results that depend on neither chunking, batching nor threads; its caches, their
keys, resumption and damaged chunks; bad experiments.  (Its receivers against the package's own:
``test_engine_receivers.py``.)"""

import json
import os
import signal as os_signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from dpe5g.phy import deployment, signal
from dpe5g.receivers import correlogram, cost, dpe, receiver, search_config
from dpe5g.simulation import chunk_cache, code_key, engine, experiment, results, store, trials

SMALL = dict(name="test", n_trials=6, seed=1, snrs_db=(15.0, 30.0), m_values=(4, 6),
             search=search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=3.0))


def test_results_do_not_depend_on_chunking_or_batching(tmp_path):
    # 6 trials in batches of 4: the last batch is filled up with copies of its last trial, which are dropped
    a = engine.run(experiment.Experiment.build(chunk_trials=6, **SMALL), cache=tmp_path / "a", progress=False,
                       batch_size=4)
    b = engine.run(experiment.Experiment.build(chunk_trials=2, **SMALL), cache=tmp_path / "b", progress=False)
    assert engine.BATCH_SIZE["grid"] == 2  # (the default: no filled-up batch, and the program other tests compile)
    for f in results.Results.FIELDS:
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=1e-9, err_msg=f)
    assert a.error_m.shape == (6, 2, 2) and a.los.shape == (6, 6)
    # a longer run reuses nothing it should not: its first trials equal the short run's
    c = engine.run(experiment.Experiment.build(chunk_trials=2, **{**SMALL, "n_trials": 8}), cache=tmp_path / "b",
                       progress=False)
    np.testing.assert_allclose(c.error_m[:6], b.error_m, atol=1e-9)


def test_results_do_not_depend_on_threads(tmp_path):
    # the certified search (one trial per batch) with several batches of a chunk computed at once, in threads
    e = experiment.Experiment.build(**{**SMALL, "centring": "prior", "prior_kind": "gaussian", "prior_scale_m": 1.0,
                                 "search": search_config.SearchConfig(method="bnb", half_width_m=3.0), "chunk_trials": 6})
    one = engine.run(e, cache=tmp_path / "one", progress=False, workers=1)
    three = engine.run(e, cache=tmp_path / "three", progress=False, workers=3)
    for f in results.Results.FIELDS:
        np.testing.assert_array_equal(getattr(one, f), getattr(three, f), err_msg=f)
    with pytest.raises(ValueError, match="workers must be an integer in"):
        engine.run(e, cache=tmp_path / "one", progress=False, workers=0)
    # centred on the OTDoA fixes, which are solved piece by piece beside the DPE of the piece before
    o = experiment.Experiment.build(**{**SMALL, "centring": "otdoa", "otdoa": True, "chunk_trials": 6})
    whole = engine.run(o, cache=tmp_path / "o6", progress=False, workers=3, batch_size=1)
    single = engine.run(experiment.Experiment.build(**{**SMALL, "centring": "otdoa", "otdoa": True, "chunk_trials": 1}),
                            cache=tmp_path / "o1", progress=False, workers=1, batch_size=1)
    for f in results.Results.FIELDS + results.Results.OTDOA_FIELDS:
        np.testing.assert_array_equal(getattr(whole, f), getattr(single, f), err_msg=f)


def test_run_at_fewer_snrs_reads_a_cached_run_at_more(tmp_path, monkeypatch):
    sup = experiment.Experiment.build(**{**SMALL, "snrs_db": (15.0, 30.0, 45.0), "chunk_trials": 2})
    sub = experiment.Experiment.build(**{**SMALL, "name": "sub", "snrs_db": (45.0, 15.0), "n_trials": 8, "chunk_trials": 2})
    other_seed = experiment.Experiment.build(**{**SMALL, "name": "seed2", "seed": 2, "snrs_db": (15.0, 30.0, 45.0),
                                          "n_trials": 8, "chunk_trials": 2})
    alone = engine.run(sub, cache=tmp_path / "alone", progress=False)
    engine.run(sup, cache=tmp_path / "shared", progress=False)
    engine.run(other_seed, cache=tmp_path / "shared", progress=False)  # its trials are not sub's
    computed = []
    call = engine.ChunkRunner.__call__
    monkeypatch.setattr(engine.ChunkRunner, "__call__",
                        lambda self, a, b, *k: computed.append((a, b)) or call(self, a, b, *k))
    shared = engine.run(sub, cache=tmp_path / "shared", progress=False)
    assert computed == [(6, 8)]  # trials 0-5 sliced from sup's chunks, the rest computed
    for f in results.Results.FIELDS:
        np.testing.assert_array_equal(getattr(alone, f), getattr(shared, f), err_msg=f)


def test_default_workers_reads_the_environment(monkeypatch):
    monkeypatch.setenv("DPE5G_WORKERS", "3")
    assert engine.default_workers() == 3
    monkeypatch.setenv("DPE5G_WORKERS", "two")
    with pytest.raises(ValueError, match="DPE5G_WORKERS must be an integer in"):
        engine.default_workers()
    monkeypatch.delenv("DPE5G_WORKERS")
    assert engine.default_workers() >= 1


def test_reverse_order_and_chunks_written_meanwhile(tmp_path, monkeypatch):
    """``run(reverse=True)`` (``dpe5g warm``) gives the forward run's results to the bit; a chunk another process wrote
    after ``missing`` listed it is read, not computed again."""
    e = experiment.Experiment.build(chunk_trials=2, **SMALL)
    fwd = engine.run(e, cache=tmp_path / "f", progress=False)
    rev = engine.run(e, cache=tmp_path / "r", progress=False, reverse=True)
    for f in results.Results.FIELDS:
        np.testing.assert_array_equal(getattr(fwd, f), getattr(rev, f), err_msg=f)
    calls = []
    monkeypatch.setattr(chunk_cache.ChunkCache, "missing", lambda self: list(self.chunks))  # "not there yet"
    monkeypatch.setattr(engine.ChunkRunner, "__call__", lambda self, *a: calls.append(a))
    again = engine.run(e, cache=tmp_path / "f", progress=False)
    assert calls == []
    np.testing.assert_array_equal(again.error_m, fwd.error_m)


def test_stale_temporaries_only_of_dead_writers_are_removed(tmp_path):
    from dpe5g.common import _io

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    mine = tmp_path / f".trials-0000000-0000002.npz.{os.getpid()}.abc123.tmp"
    gone = tmp_path / f".trials-0000002-0000004.npz.{dead.pid}.xyz789.tmp"
    old = tmp_path / ".trials-0000004-0000006.npz.k2j4h5.tmp"  # without a pid: an older writer's
    for p in (mine, gone, old):
        p.write_bytes(b"partial")
    assert sorted(_io.remove_stale_temporaries(tmp_path)) == sorted([gone, old])
    assert mine.exists() and not gone.exists() and not old.exists()
    with _io.atomic_target(tmp_path / "x.npz") as tmp:
        assert f".{os.getpid()}." in tmp.name and _io.remove_stale_temporaries(tmp_path) == []  # a live write stays
        tmp.write_bytes(b"whole")
    assert (tmp_path / "x.npz").read_bytes() == b"whole"


def test_cache_is_keyed_by_config(tmp_path):
    e1 = experiment.Experiment.build(**SMALL)
    e2 = experiment.Experiment.build(**{**SMALL, "seed": 2})
    assert e1.key() != e2.key()
    assert e1.key() == experiment.Experiment.build(**{**SMALL, "n_trials": 60, "chunk_trials": 7}).key()


def test_interrupted_run_resumes_to_identical_results(tmp_path):
    """Start a run in a subprocess, SIGKILL it after its first chunk is on disk, resume, compare."""
    cache = tmp_path / "killed"
    cfg = dict(SMALL, n_trials=10)
    plain = {k: v for k, v in cfg.items() if k != "search"}
    script = textwrap.dedent(f"""
        from dpe5g import engine, experiment
        from dpe5g.receivers import search_config
        e = experiment.Experiment.build(chunk_trials=1, search=search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=3.0),
                                  **{plain!r})
        engine.run(e, cache={str(cache)!r}, progress=False, batch_size=1)
    """)
    err = tmp_path / "stderr.txt"
    with open(err, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=f)
    e = experiment.Experiment.build(chunk_trials=1, **cfg)
    d = chunk_cache.cache_dir(e, cache)
    t0 = time.time()
    while time.time() - t0 < 240:
        if d.exists() and len(list(d.glob("trials-*.npz"))) >= 2:
            break
        if proc.poll() is not None:
            pytest.fail(f"the run ended before it could be killed: {err.read_text()[-500:]}")
        time.sleep(0.05)
    proc.send_signal(os_signal.SIGKILL)
    proc.wait()
    done = sorted(d.glob("trials-*.npz"))
    assert 2 <= len(done) < 10, f"{len(done)} chunks on disk when killed"
    mtimes = {p.name: p.stat().st_mtime_ns for p in done}
    resumed = engine.run(e, cache=cache, progress=False, batch_size=1)
    assert all(p.stat().st_mtime_ns == mtimes[p.name] for p in done)  # finished chunks were loaded, not redone
    fresh = engine.run(e, cache=tmp_path / "fresh", progress=False, batch_size=1)
    for f in results.Results.FIELDS:
        np.testing.assert_array_equal(getattr(resumed, f), getattr(fresh, f), err_msg=f)


def test_two_of_four_and_link_budget_modes(tmp_path):
    e = experiment.Experiment.build(name="t4", n_trials=4, seed=3, snr_mode="link_budget", snrs_db=(), m_values=(4,),
                              los_mode="two_of_four", search=search_config.SearchConfig(half_width_m=3.0), otdoa=True)
    r = engine.run(e, cache=tmp_path, progress=False)
    assert np.all(r.los.sum(axis=1) == 2)
    n_det = len(experiment.OTDOA_DETECTORS)
    assert r.otdoa_xyz.shape == (4, 1, n_det, 1, 3) and r.otdoa_ok.dtype == bool
    assert np.all(np.isfinite(r.otdoa_error_m))
    # the estimated ToAs carry the common clock bias and are within a few samples of the geometric ones
    geo = np.linalg.norm(r.ue_xyz[:, None, :] - deployment.tst().bs_xyz[r.bs_index], axis=-1) / 3e8
    for k in range(n_det):
        assert np.all(np.abs(r.otdoa_toa_s[:, 0, k, :] - r.clock_bias_s[:, None] - geo) < 40 * 8.14e-9)
    assert r.link_snr_db.shape == (4, 1, 4) and np.all(np.isfinite(r.link_snr_db))
    rows = r.table()
    assert len(rows) == 4 and {"trial", "snr_db", "m", "error_m", "n_los", "edge", "otdoa_first_path_error_m",
                              "otdoa_peak_ok"} <= set(rows[0])
    r.write_csv(tmp_path / "t.csv")
    assert (tmp_path / "t.csv").read_text().count("\n") == 5  # the header, 4 rows
    assert sorted(rows[0][f"link{k}_los"] for k in range(1, 5)) == [0, 0, 1, 1]
    r.write_provenance(tmp_path / "t.json", "abc1234")
    doc = json.loads((tmp_path / "t.json").read_text())
    assert doc["experiment"]["los_mode"] == "two_of_four" and set(doc["columns"]) == set(rows[0])
    assert doc["provenance"]["commit"] == "abc1234"


@pytest.mark.parametrize("kwargs, needle", [
    (dict(snrs_db=(float("nan"),)), "snr_db must be finite"),
    (dict(m_values=(12, 6)), "increasing"),
    (dict(m_values=(2,)), "m_values entry"),
    (dict(los_mode="two_of_four"), "must end in 4"),
    (dict(snr_mode="link_budget", snrs_db=(10.0,)), "must be empty"),
    (dict(channel="traced", deployment="/etc/hostname"), "a traced city is a city of the results store by name, or"),
    (dict(delay_spread_s=65.0), "nanoseconds"),
    (dict(los_mode="sometimes"), "los_mode must be one of"),
    (dict(n_trials=0), "n_trials"),
    (dict(toa_method="strongest"), "toa_method must be one of"),
    (dict(centring="oracle"), "centring must be one of"),
    (dict(centring="otdoa"), "set otdoa=True"),
    (dict(prior_scale_m=-1.0), "prior_scale_m"),
    (dict(prs_reuse=3), "prs_reuse must be one of"),
    (dict(prs_reuse=6, search=search_config.SearchConfig(method="bnb")), "snr_mode must be 'link_budget' or 'nearest'"),
    (dict(prs_reuse=6, snr_mode="nearest"), "needs the certified search"),
    (dict(snr_mode="nearest", snrs_db=()), "snrs_db must list"),
    (dict(prs_reuse=6, snr_mode="nearest", co_channel=1, search=search_config.SearchConfig(method="bnb")), "co_channel"),
])
def test_bad_experiments(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        experiment.Experiment.build(**kwargs)


def test_too_many_bs_for_the_deployment():
    with pytest.raises(ValueError, match="must not exceed"):
        experiment.Experiment.build(m_values=(6, 30)).load_deployment()


def test_honest_centrings_see_no_truth(tmp_path):
    """Prior and OTDoA centring: the window's centre is not the truth (prior) or is the OTDoA fix, and the
    clock-bias window is centred on 0 and sized from the clock model."""
    bnb = search_config.SearchConfig(method="bnb", half_width_m=4.0)  # (test_window_as_input's search: one compile)
    base = dict(n_trials=4, seed=3, snr_mode="link_budget", snrs_db=(), m_values=(4,), search=bnb, chunk_trials=2)
    pr = engine.run(experiment.Experiment.build(name="p", centring="prior", **base), cache=tmp_path, progress=False)
    off = np.linalg.norm(pr.center_xyz[:, 0, 0, :2] - pr.ue_xyz[:, :2], axis=-1)
    assert np.all(off > 1e-3) and np.all(pr.center_xyz[:, 0, 0, 2] == pr.ue_xyz[:, 2])
    e = experiment.Experiment.build(name="p", centring="prior", **base)
    assert e.receiver_search().bias_half_width_m == pytest.approx(3 * 5e-9 * 299_792_458.0)
    ot = engine.run(experiment.Experiment.build(name="o", centring="otdoa", otdoa=True, **base), cache=tmp_path,
                        progress=False)
    k = experiment.OTDOA_DETECTORS.index("first_path")
    np.testing.assert_allclose(ot.center_xyz[:, 0, 0, :2], ot.otdoa_xyz[:, 0, k, 0, :2])
    assert np.all(np.isfinite(ot.gap)) and np.all(ot.est_bias_s * 299_792_458.0 <= 4.5)


def test_window_as_input_matches_a_direct_fix_for_every_l(tmp_path):
    """Experiments that differ only in L share one compiled trial function (the window enters as an input); each
    L's engine fix must equal the public ``dpe.fix`` run directly on that trial's signals with that L."""
    import dataclasses

    bnb = search_config.SearchConfig(method="bnb", half_width_m=4.0)
    base = experiment.Experiment.build(name="w", n_trials=2, seed=5, snr_mode="link_budget", snrs_db=(), m_values=(4,),
                                 centring="prior", search=bnb, chunk_trials=2)
    for n_taps in (12, 3):  # the second run reuses the first one's compiled function
        e = base.replace(search=dataclasses.replace(bnb, n_taps=n_taps))
        res = engine.run(e, cache=tmp_path, progress=False)
        for t in range(e.run.n_trials):
            ex = trials.example(e, t)
            center = np.concatenate([res.center_xyz[t, 0, 0], [0.0]])
            r = dpe.fix(ex.y, ex.prs, ex.bs_xyz, center, e.receiver_search())
            np.testing.assert_allclose(res.est_xyz[t, 0, 0], r.xyz, atol=1e-9, err_msg=str(n_taps))
    assert correlogram.window_spectrum(1, 8)[0] == 1 and correlogram.window_spectrum(3, 8)[0] == 3


def test_certified_search_is_traced_once_for_experiments_with_its_search_and_m(tmp_path, caplog):
    """The certified search (the slow program to compile) runs as a program of its own per search config, M values
    and number of SNRs: an experiment that differs from an earlier one only in its draws (LoS model), SNR values or
    receiver window L must not trace it again, while its own draws and correlograms are traced (the log's positive
    control)."""
    import dataclasses
    import logging

    import jax

    bnb = search_config.SearchConfig(method="bnb", half_width_m=2.0, box_m=1.0)
    first = experiment.Experiment.build(name="a", n_trials=1, chunk_trials=1, seed=3, snrs_db=(20.0,), m_values=(4,),
                                  centring="prior", search=bnb)
    engine.run(first, cache=tmp_path, progress=False)
    other = first.replace(name="b", los_mode="all_los", snrs_db=(10.0,),
                                search=dataclasses.replace(bnb, n_taps=4))
    with jax.log_compiles(True), caplog.at_level(logging.WARNING, logger="jax"):
        engine.run(other, cache=tmp_path, progress=False)
    traced = [r.getMessage() for r in caplog.records if "Finished tracing" in r.getMessage()]
    assert any("bnb_prep" in m for m in traced), traced
    assert not any("certified_fix" in m for m in traced), traced


def test_engine_signal_is_the_public_signal_path():
    """The engine simulates in the frequency domain; its samples must be ``signal.received_noiseless`` of the
    trial's own channel (per-link profile, gains, delays, ToA, clock bias), and its noise AWGN of the SNR's
    variance."""
    e = experiment.Experiment.build(name="s", n_trials=3, seed=4, snrs_db=(20.0, 30.0), m_values=(6,))
    for t in range(e.run.n_trials):
        ex = trials.example(e, t)
        ref = np.asarray(signal.received_noiseless(ex.prs, ex.gains, ex.delays_s, cost.toa(ex.ue_xyz, ex.bs_xyz),
                                                   float(ex.clock_bias_s)))
        np.testing.assert_allclose(ex.y0, ref, atol=1e-12 * np.abs(ref).max())
        assert np.all((ex.delays_s[:, 0] == 0) & (np.abs(ex.gains).sum(axis=1) > 0))
        noise = ex.y - ex.y0
        var = float(np.asarray(signal.noise_variance(20.0, ex.prs))[0])
        assert abs(np.mean(np.abs(noise) ** 2) / var - 1) < 0.05


def test_cache_key_follows_code_not_prose(tmp_path):
    """``code_digest`` ignores docstrings, comments and layout, and changes with any change of code."""
    a = tmp_path / "a.py"
    a.write_text('"""Doc."""\n\ndef f(x):\n    """Say."""\n    return x + 1  # one\n')
    b = tmp_path / "b.py"
    b.write_text('"""Other doc."""\n\n\ndef f(x):\n    # a comment\n    return x + 1\n')
    c = tmp_path / "c.py"
    c.write_text('"""Doc."""\n\ndef f(x):\n    """Say."""\n    return x + 2  # one\n')
    assert code_key.code_digest(a) == code_key.code_digest(b) != code_key.code_digest(c)


def test_code_version_covers_every_module_the_engine_imports(tmp_path):
    """No list kept by hand: the modules come from the engine's imports (search_config.py, split out of dpe.py, was
    once missing from such a list, and a change of the grid's levels kept every cache key).  In a copy of the
    package, a change of code in search_config.py, or a new module that the engine's modules import, changes the
    code version; a module nothing imports does not."""
    import shutil

    pkg = tmp_path / "dpe5g"
    shutil.copytree(code_key.PACKAGE, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    mods = code_key.source_modules(pkg)
    assert {"receivers/search_config.py", "simulation/engine.py", "simulation/trials.py", "simulation/store.py",
            "__init__.py", "phy/__init__.py"} <= set(mods)
    assert not {"cli/main.py", "figures/plots.py", "figures/registry.py", "studies/paper.py"} & set(mods)
    base = code_key.code_version(pkg)
    assert base == code_key.code_version()
    (pkg / "lonely.py").write_text("X = 1\n")
    assert code_key.code_version(pkg) == base
    sc = pkg / "receivers" / "search_config.py"
    sc.write_text(sc.read_text().replace("def steps(self", "def unused(self):\n        return 0\n\n    def steps(self", 1))
    changed = code_key.code_version(pkg)
    assert changed != base
    (pkg / "helper.py").write_text("def offset():\n    return 0.0\n")
    tr = pkg / "simulation" / "trials.py"
    tr.write_text(tr.read_text().replace("from __future__ import annotations\n",
                                         "from __future__ import annotations\n\nfrom ..helper import offset\n", 1))
    assert "helper.py" in code_key.source_modules(pkg) and code_key.code_version(pkg) != changed


def test_code_version_follows_nested_packages(tmp_path):
    """In a copy of the package grown a subpackage: every package's ``__init__`` counts; a module the engine reaches
    through ``from ..sub import leaf``, and the ones leaf reaches by relative imports of depth 1 and 2 (``from .inner
    import deeper``, ``from ..phy.nr import C``), are keyed by their path inside the package; a change of code in the
    deepest changes the version, a change of its docstring does not."""
    import shutil

    pkg = tmp_path / "dpe5g"
    shutil.copytree(code_key.PACKAGE, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    base = code_key.code_version(pkg)
    (pkg / "sub" / "inner").mkdir(parents=True)
    (pkg / "sub" / "__init__.py").write_text('"""A subpackage."""\n\nLEVEL = 1\n')
    (pkg / "sub" / "inner" / "__init__.py").write_text("")
    deeper = pkg / "sub" / "inner" / "deeper.py"
    deeper.write_text('"""Deeper."""\n\n\ndef g():\n    return 1\n')
    (pkg / "sub" / "leaf.py").write_text('"""Leaf."""\n\nfrom ..phy.nr import C\nfrom .inner import deeper\n\n\n'
                                         'def f():\n    return deeper.g() * C\n')
    mods = code_key.source_modules(pkg)
    assert {"sub/__init__.py", "sub/inner/__init__.py"} <= set(mods) and "sub/leaf.py" not in mods
    with_inits = code_key.code_version(pkg)
    assert with_inits != base
    eng = pkg / "simulation" / "engine.py"
    eng.write_text(eng.read_text().replace("from __future__ import annotations\n",
                                           "from __future__ import annotations\n\nfrom ..sub import leaf\n", 1))
    assert {"sub/leaf.py", "sub/inner/deeper.py", "phy/nr.py"} <= set(code_key.source_modules(pkg))
    reached = code_key.code_version(pkg)
    assert reached != with_inits
    deeper.write_text('"""Deeper still, and said at more length."""\n\n\ndef g():\n    return 1\n')
    assert code_key.code_version(pkg) == reached
    deeper.write_text('"""Deeper."""\n\n\ndef g():\n    return 10\n')
    assert code_key.code_version(pkg) != reached


def test_settings_as_lists_and_numpy_values_key_as_plain_numbers():
    plain = experiment.Experiment.build(**SMALL)
    given = experiment.Experiment.build(**{**SMALL, "snrs_db": [np.float64(15.0), 30], "m_values": np.array([4, 6]),
                                           "seed": np.int64(1), "n_trials": np.int32(6)})
    assert given == plain and given.key() == plain.key() and given.config_key() == plain.config_key()
    assert type(given.run.seed) is int and given.receiver.m_values == (4, 6)
    assert experiment.Experiment.build(m_values=[6, 12]).receiver.m_values == (6, 12)
    # an int where a float is declared, a whole float where an int is: the same experiment and key
    ints = experiment.Experiment.build(**{**SMALL, "seed": 1.0, "m_values": (4.0, 6),
                                          "search": search_config.SearchConfig(half_width_m=3, bias_half_width_m=3)})
    assert ints == plain and ints.config_key() == plain.config_key() and type(ints.run.seed) is int
    assert type(ints.receiver.search.half_width_m) is float
    assert experiment.Experiment.build(prior_scale_m=5).config_key() == experiment.Experiment.build(
        prior_scale_m=5.0).config_key()
    with pytest.raises(ValueError, match="seed must be an integer"):
        experiment.Experiment.build(seed=1.5)
    # the link-budget mode takes its SNRs from the path loss: built without an SNR list, the same as with an empty one
    budget = experiment.Experiment.build(snr_mode="link_budget", m_values=(4,))
    assert budget == experiment.Experiment.build(snr_mode="link_budget", snrs_db=(), m_values=(4,))
    assert budget.links.snrs_db == () and budget.links.snr_mode == "link_budget"
    with pytest.raises(ValueError, match="snrs_db must be empty when snr_mode is 'link_budget'"):
        experiment.Experiment.build(snr_mode="link_budget", snrs_db=(10.0,))


def test_code_version_does_not_depend_on_the_locale():
    """The sources are read as UTF-8 whatever the locale (an ASCII locale failed on the first non-ASCII byte, and
    another 8-bit one would have given another code version, so workers of one checkout would have disagreed)."""
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0",
           "PYTHONIOENCODING": "ascii"}
    r = subprocess.run([sys.executable, "-c", "import locale; from dpe5g.simulation import code_key; "
                        "print(locale.getpreferredencoding(), code_key.code_version())"],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    encoding, version = r.stdout.split()
    assert encoding.lower() not in ("utf-8", "utf8") and version == code_key.code_version()


def test_a_damaged_cache_chunk_is_named_set_aside_and_computed_again(tmp_path, capsys):
    e = experiment.Experiment.build(**{**SMALL, "chunk_trials": 2})
    good = engine.run(e, cache=tmp_path, progress=False)
    d = chunk_cache.cache_dir(e, tmp_path)
    chunk = d / "trials-0000002-0000004.npz"
    other = experiment.Experiment.build(**{**SMALL, "seed": 2, "chunk_trials": 2})
    engine.run(other, cache=tmp_path, progress=False)
    foreign = (chunk_cache.cache_dir(other, tmp_path) / chunk.name).read_bytes()  # another experiment's chunk
    capsys.readouterr()
    moved = (d / "trials-0000000-0000002.npz").read_bytes()  # this experiment's chunk of other trials
    for kind, bad in (("truncated", chunk.read_bytes()[:300]), ("foreign", foreign), ("moved", moved),
                      ("bit flipped", bytes(b ^ (i == 900) * 4 for i, b in enumerate(chunk.read_bytes())))):
        chunk.write_bytes(bad)
        again = engine.run(e, cache=tmp_path, progress=False)
        for f in results.Results.FIELDS:
            np.testing.assert_array_equal(getattr(again, f), getattr(good, f), err_msg=f"{kind}: {f}")
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"cache file {chunk} is damaged" in err[0] and "set aside" in err[0], (kind, err)
        assert (d / f"{chunk.name}.damaged").read_bytes() == bad, kind


def test_a_damaged_file_another_process_set_aside_or_rewrote_is_left_alone(tmp_path):
    """Two processes reading one cache: the second to find a damaged file either finds it gone (set aside by the
    first) or rewritten since it read it (computed again by the first); neither is an error or moved."""
    path = tmp_path / "trials-0000000-0000002.npz"
    assert chunk_cache.set_aside(path, "gone") is None and not list(tmp_path.iterdir())
    path.write_bytes(b"damaged")
    seen = path.stat()
    time.sleep(0.01)
    path.write_bytes(b"computed again by another process")
    assert chunk_cache.set_aside(path, "read before the rewrite", seen) is None
    assert path.read_bytes() == b"computed again by another process" and not path.with_name(path.name + ".damaged").exists()


def test_a_damaged_chunk_that_cannot_be_set_aside_says_so(tmp_path, monkeypatch):
    """A read-only cache: the damaged chunk cannot be moved, and the run says that, not only "Read-only file
    system"."""
    from dpe5g.common.errors import Failure

    e = experiment.Experiment.build(**{**SMALL, "chunk_trials": 2})
    engine.run(e, cache=tmp_path, progress=False)
    chunk = chunk_cache.cache_dir(e, tmp_path) / "trials-0000002-0000004.npz"
    chunk.write_bytes(chunk.read_bytes()[:300])

    real = os.replace

    def read_only(src, dst):  # the move aside fails as on a read-only filesystem; other moves as usual
        if str(dst).endswith(".damaged"):
            raise OSError(30, "Read-only file system")
        return real(src, dst)

    monkeypatch.setattr(store.os, "replace", read_only)
    with pytest.raises(Failure, match=f"cache file {chunk} is damaged .* cannot be set aside .*Read-only file system"):
        engine.run(e, cache=tmp_path, progress=False)
