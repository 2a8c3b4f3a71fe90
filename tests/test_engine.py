import json
import os
import signal as os_signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from dpe5g import (chunk_cache, code_key, correlogram, cost, deployment, dpe, draw, engine, experiment, grid_search,
                   receiver, results, search_config, signal, store, trial_draw, trials)

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
    from dpe5g import _io

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
        from dpe5g import engine, experiment, search_config
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
    (dict(snr_mode="link_budget"), "must be empty"),
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
    shutil.copytree(os.path.dirname(experiment.__file__), pkg, ignore=shutil.ignore_patterns("__pycache__"))
    mods = code_key.source_modules(pkg)
    assert {"search_config.py", "engine.py", "trials.py", "store.py", "__init__.py"} <= set(mods)
    assert not {"cli.py", "plots.py", "figures.py", "paper.py"} & set(mods)
    base = code_key.code_version(pkg)
    assert base == code_key.code_version()
    (pkg / "lonely.py").write_text("X = 1\n")
    assert code_key.code_version(pkg) == base
    sc = pkg / "search_config.py"
    sc.write_text(sc.read_text().replace("def steps(self", "def unused(self):\n        return 0\n\n    def steps(self", 1))
    changed = code_key.code_version(pkg)
    assert changed != base
    (pkg / "helper.py").write_text("def offset():\n    return 0.0\n")
    tr = pkg / "trials.py"
    tr.write_text(tr.read_text().replace("from __future__ import annotations\n",
                                         "from __future__ import annotations\n\nfrom .helper import offset\n", 1))
    assert "helper.py" in code_key.source_modules(pkg) and code_key.code_version(pkg) != changed


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


def test_code_version_does_not_depend_on_the_locale():
    """The sources are read as UTF-8 whatever the locale (an ASCII locale failed on the first non-ASCII byte, and
    another 8-bit one would have given another code version, so workers of one checkout would have disagreed)."""
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0",
           "PYTHONIOENCODING": "ascii"}
    r = subprocess.run([sys.executable, "-c", "import locale; from dpe5g import code_key; "
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
    from dpe5g.errors import Failure

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


def test_nested_grid_fixes_equal_one_fix_per_m():
    """The engine's grid search shares its first level between the M values (``grid_search.nested_grid_fixes``); each M's
    fix must equal ``receiver.fix_in_window`` run on that M's BSs alone, on urban trials at several SNRs and on a shifted centre."""
    import jax
    import jax.numpy as jnp

    e = experiment.Experiment.build(name="n", n_trials=4, seed=12, snrs_db=(10.0, 40.0), m_values=(3, 6, 12))
    cfg = e.receiver_search()
    nested_fn = jax.jit(lambda corr, g, bs, c: grid_search.nested_grid_fixes(corr, g, bs, c, cfg, e.receiver.m_values))
    fix_fn = jax.jit(lambda g, bs, c, corr: receiver.fix_in_window(g, bs, c, cfg, corr=corr))  # traced once per M
    for t in range(e.run.n_trials):
        for s in range(2):
            ex = trials.example(e, t, snr_index=s)
            g = correlogram.ls_spectrum(signal.demodulate(ex.y), jnp.asarray(ex.prs))
            corr = receiver.receiver_correlogram(g, cfg)
            center = jnp.asarray(np.concatenate([ex.ue_xyz + [1.3 * t, -0.7 * s, 0.0], [299_792_458.0 * ex.clock_bias_s]]))
            nested = nested_fn(corr, g, jnp.asarray(ex.bs_xyz), center)
            for j, m in enumerate(e.receiver.m_values):
                one = fix_fn(g[:m], jnp.asarray(ex.bs_xyz[:m]), center, corr[:m])
                np.testing.assert_array_equal(np.asarray(nested.q[j]), np.asarray(one.q), err_msg=f"{t} {s} {m}")
                assert bool(nested.edge[j]) == bool(one.edge)
    with pytest.raises(ValueError, match="cfg.method must be 'grid'"):
        grid_search.nested_grid_fixes(corr, g, jnp.asarray(ex.bs_xyz), center, search_config.SearchConfig(method="bnb"), e.receiver.m_values)


def test_range_offsets_and_error_summary(tmp_path):
    """``studies.range_offsets_m`` reads each fix's ToA of each used link (NaN beyond M) against ``cost.toa`` at the
    truth; ``results.error_summary`` against NumPy."""
    from dpe5g import studies

    e = experiment.Experiment.build(name="o", n_trials=3, seed=2, snrs_db=(20.0,), m_values=(3, 5))
    res = engine.run(e, cache=tmp_path, progress=False)
    off = studies.range_offsets_m(res)
    assert off.shape == (3, 1, 2, 5)
    assert np.all(np.isnan(off[:, :, 0, 3:])) and not np.any(np.isnan(off[:, :, 0, :3]))
    bs = e.load_deployment().bs_xyz
    c = 299_792_458.0
    for t in range(3):
        for j in range(2):
            ref = c * (np.asarray(cost.toa(res.est_xyz[t, 0, j], bs[res.bs_index[t]], res.est_bias_s[t, 0, j]))
                       - np.asarray(cost.toa(res.ue_xyz[t], bs[res.bs_index[t]], res.clock_bias_s[t])))
            m = e.receiver.m_values[j]
            np.testing.assert_allclose(off[t, 0, j, :m], ref[:m], atol=1e-6)
    err = np.array([0.0, 1.0, 2.0, 10.0])
    s = results.error_summary(err, edge=np.array([0, 0, 1, 1], bool), certified=np.ones(4, bool))
    assert s["rmse_m"] == pytest.approx(np.sqrt(105 / 4)) and s["median_m"] == 1.5
    assert s["p99_m"] == pytest.approx(np.quantile(err, 0.99)) and s["edge_share"] == 0.5
    assert s["certified_share"] == 1.0


def test_readings_delay_spread_definition_and_snr_convention():
    """The readings of Chapter 7 as Experiment fields: "span" scales both profiles so their last tap comes
    delay_spread_s after the first; "total" SNRs are 10 log10 N dB above the per-sample SNR they simulate, in both
    SNR modes; bad values name the field."""
    base = experiment.Experiment.build(name="r", n_trials=2, seed=3, snrs_db=(30.0,), m_values=(6,))
    span = trials.example(base.replace(delay_spread_def="span"), 0)
    rms = trials.example(base, 0)
    assert np.max(span.delays_s) == pytest.approx(65e-9, rel=1e-12)
    assert np.max(rms.delays_s) > 500e-9  # TDL-C's last tap at 8.65 RMS spreads
    np.testing.assert_array_equal(span.los, rms.los)
    gain = 10 * np.log10(4096)
    for kw in (dict(snrs_db=(30.0,)), dict(snr_mode="link_budget", snrs_db=())):
        per = trials.example(base.replace(**kw), 1)
        tot = trials.example(base.replace(snr_convention="total", **kw), 1)
        np.testing.assert_allclose(tot.link_snr_db, per.link_snr_db - gain, atol=1e-12)
        np.testing.assert_array_equal(tot.y0, per.y0)
    same = trials.example(base.replace(snrs_db=(30.0 - gain,)), 1)
    tot = trials.example(base.replace(snr_convention="total"), 1)
    np.testing.assert_allclose(tot.y, same.y, atol=1e-12 * np.abs(same.y).max())
    with pytest.raises(ValueError, match="delay_spread_def"):
        experiment.Experiment.build(delay_spread_def="first_to_last")
    with pytest.raises(ValueError, match="snr_convention"):
        experiment.Experiment.build(snr_convention="post_correlation")


def test_grid_search_centred_on_each_m_otdoa_fix(tmp_path):
    """Centring "otdoa" with the grid search and two M values: each M's window is centred on that M's own OTDoA fix
    (the first level is shared between the M values only around the truth), and its fix is the public ``dpe.fix``
    there."""
    e = experiment.Experiment.build(name="g", n_trials=2, seed=6, snr_mode="link_budget", snrs_db=(), m_values=(4, 8),
                              centring="otdoa", otdoa=True, search=search_config.SearchConfig(half_width_m=4.0))
    res = engine.run(e, cache=tmp_path, progress=False)
    det = experiment.OTDOA_DETECTORS.index(e.receiver.toa_method)
    for t in range(e.run.n_trials):
        ex = trials.example(e, t)
        for j, m in enumerate(e.receiver.m_values):
            np.testing.assert_allclose(res.center_xyz[t, 0, j, :2], res.otdoa_xyz[t, 0, det, j, :2], atol=1e-9)
            center = np.concatenate([res.center_xyz[t, 0, j], [0.0]])
            r = dpe.fix(ex.y[:m], ex.prs[:m], ex.bs_xyz[:m], center, e.receiver_search())
            np.testing.assert_allclose(res.est_xyz[t, 0, j], r.xyz, atol=1e-9)
    assert not np.allclose(res.center_xyz[:, 0, 0], res.center_xyz[:, 0, 1])


REUSE = dict(name="r", n_trials=2, seed=4, snr_mode="nearest", snrs_db=(20.0,), m_values=(12,),
             search=search_config.SearchConfig(method="bnb", half_width_m=3.0, bias_half_width_m=3.0))


def test_prs_reuse_receives_the_sum_of_the_co_channel_bss():
    """With reuse, the UE receives on each resource the sum of its BSs' signals (links and the other BSs of the
    deployment) at their relative powers plus one noise: co-channel links read the same received signal, scaled to
    their own power; the links' draws are those of the experiment without reuse; SINR from the powers."""
    e = experiment.Experiment.build(prs_reuse=6, **REUSE)
    plain = trials.example(experiment.Experiment.build(**REUSE), 0)
    ex = trials.example(e, 0)
    for k in ("ue_xyz", "clock_bias_s", "bs_index", "los", "gains", "link_snr_db"):
        np.testing.assert_array_equal(getattr(ex, k), getattr(plain, k), err_msg=k)
    res_all, _ = deployment.tst().prs_plan(6)
    np.testing.assert_array_equal(ex.reuse.res, res_all[ex.bs_index])
    assert ex.reuse.co_channel.y0.shape == (deployment.tst().n_bs - 12, 4096)
    # every link's pilots: the 3276 active subcarriers, the energy of the paper's symbol
    assert np.all(np.count_nonzero(ex.prs, axis=1) == 3276)
    np.testing.assert_allclose(np.sum(np.abs(ex.prs) ** 2, axis=1), 4096)
    sigma = 10 ** (-ex.link_snr_db / 20)
    sigma_x = 10 ** (-ex.reuse.co_channel.snr_db / 20)
    s = np.asarray(signal.demodulate(ex.y0))
    rx = {r: (s[ex.reuse.res == r] / sigma[ex.reuse.res == r, None]).sum(0)
          + (ex.reuse.co_channel.y0[ex.reuse.co_channel.res == r] / sigma_x[ex.reuse.co_channel.res == r, None]).sum(0) for r in range(6)}
    y = np.asarray(signal.demodulate(ex.y))  # in units of the noise: one receiver, one noise floor
    noise = y - np.stack([rx[r] for r in ex.reuse.res])
    assert abs(np.mean(np.abs(noise) ** 2) - 1) < 0.05
    pairs = [(i, j) for i in range(12) for j in range(i) if ex.reuse.res[i] == ex.reuse.res[j]]
    assert pairs
    for i, j in pairs:
        np.testing.assert_allclose(y[i], y[j], atol=1e-9 * np.abs(y[i]).max())
    rho = 10 ** (ex.link_snr_db / 10)
    rho_x = 10 ** (ex.reuse.co_channel.snr_db / 10)
    per_res = np.array([rho[ex.reuse.res == r].sum() + rho_x[ex.reuse.co_channel.res == r].sum() for r in range(6)])
    np.testing.assert_allclose(ex.link_sinr_db, 10 * np.log10(rho / (1 + per_res[ex.reuse.res] - rho)), atol=1e-9)
    assert np.all(ex.link_sinr_db < ex.link_snr_db)
    # without the co-channel signals: the links' own signals and the shared noise of their resource
    alone = trials.example(experiment.Experiment.build(prs_reuse=6, co_channel=False, **REUSE), 0)
    np.testing.assert_array_equal(alone.link_sinr_db, alone.link_snr_db)
    eta = np.asarray(signal.demodulate(alone.y - alone.y0 / sigma[:, None]))
    for i, j in pairs:
        np.testing.assert_allclose(eta[i], eta[j], atol=1e-9)
    assert abs(np.mean(np.abs(eta) ** 2) - 1) < 0.05


def test_prs_reuse_runs_and_reports_sinr(tmp_path):
    e = experiment.Experiment.build(prs_reuse=6, centring="prior",
                              **{**REUSE, "m_values": (4, 6), "snr_mode": "link_budget", "snrs_db": ()})
    r = engine.run(e, cache=tmp_path, progress=False)
    assert r.link_sinr_db.shape == (2, 1, 6) and np.all(r.link_sinr_db <= r.link_snr_db)
    row = r.table()[0]
    assert [k for k in row if k.startswith("link")] == [f"link{k}_{q}" for k in range(1, 7)
                                                        for q in ("los", "snr_db", "sinr_db")]  # (M = 4 and 6)
    assert all(row[f"link{k}_sinr_db"] <= row[f"link{k}_snr_db"] for k in range(1, 7))


def test_links_keep_their_received_power_where_it_differs():
    """snr_mode "link_budget": one receiver, one noise floor — each link's signal at its own received power over unit
    noise, not rescaled to unit power with the truth's SNR."""
    e = experiment.Experiment.build(name="p", n_trials=1, seed=2, snr_mode="link_budget", snrs_db=(), m_values=(6,))
    ex = trials.example(e, 0)
    sigma = 10 ** (-ex.link_snr_db / 20)
    y, y0 = np.asarray(signal.demodulate(ex.y)), np.asarray(signal.demodulate(ex.y0))
    np.testing.assert_allclose(np.mean(np.abs(y0 / sigma[:, None]) ** 2, axis=1) / np.mean(np.abs(y0) ** 2, axis=1),
                               10 ** (ex.link_snr_db / 10), rtol=1e-9)
    assert abs(np.mean(np.abs(y - y0 / sigma[:, None]) ** 2) - 1) < 0.05
    assert np.ptp(ex.link_snr_db) > 3  # the links' powers differ


def test_engine_grid_fixes_equal_the_search_on_each_snrs_whole_correlogram(tmp_path):
    """The engine mixes each SNR's correlogram from parts computed once per trial, reads it only in the search's
    window, and looks the first level up once for all SNRs (``receiver.mixed_grid_fixes``); its fixes must equal the grid
    search on each SNR's whole correlogram, computed from that SNR's received samples (``example``)."""
    import jax
    import jax.numpy as jnp

    e = experiment.Experiment.build(name="mix", n_trials=3, seed=5, snrs_db=(0.0, 15.0, 40.0), m_values=(3, 6, 12))
    cfg = e.receiver_search()
    r = engine.run(e, cache=tmp_path, progress=False)
    whole = jax.jit(lambda g, bs, c: grid_search.nested_grid_fixes(receiver.receiver_correlogram(g, cfg), g, bs, c, cfg,
                                                                   e.receiver.m_values).q)
    for t in range(e.run.n_trials):
        for s in range(e.n_snr):
            ex = trials.example(e, t, snr_index=s)
            g = correlogram.ls_spectrum(signal.demodulate(ex.y), jnp.asarray(ex.prs))
            q = whole(g, jnp.asarray(ex.bs_xyz), jnp.asarray(np.append(ex.ue_xyz, 299_792_458.0 * ex.clock_bias_s)))
            np.testing.assert_allclose(r.est_xyz[t, s], np.asarray(q)[:, :3], rtol=0, atol=1e-9, err_msg=f"{t} {s}")


def test_noise_parts_mix_to_each_snrs_correlograms():
    """Both receivers' correlograms at every SNR, mixed from the trial's parts (``receiver.spline_correlograms``,
    ``receiver.grid_windows``), equal those computed from that SNR's received spectrum: to float64 round-off for the
    certified search's spline, to complex64 round-off for the grid's windows; with the links at their own received
    powers too (snr_mode "nearest")."""
    import jax.numpy as jnp

    for mode in ("fixed", "nearest"):
        e = experiment.Experiment.build(name="parts", seed=3, snrs_db=(5.0, 30.0), m_values=(4, 8), snr_mode=mode)
        d = draw.draw_fn(e, e.load_deployment())(trial_draw.trial_key(e.run.seed, 0), 0)
        for cfg in (e.receiver_search(), search_config.SearchConfig(method="bnb")):
            window = jnp.asarray(correlogram.window_spectrum(cfg.n_taps, d.prs.shape[1])) if cfg.method == "bnb" \
                else None
            spline = receiver.spline_correlograms(d, cfg, window) if cfg.method == "bnb" else None
            parts, windows = receiver.grid_windows(d, cfg)
            assert parts is not None
            start = grid_search.grid_window(d.bs_xyz, jnp.concatenate([d.ue_xyz, d.clock_bias_s[None] * 299_792_458.0]), cfg)
            for s in range(e.n_snr):
                g = correlogram.ls_spectrum(receiver.spectrum_at(d, s), d.prs)
                if cfg.method == "bnb":
                    ref = np.asarray(receiver.receiver_correlogram(g, cfg, window))
                    np.testing.assert_allclose(np.asarray(spline(s)), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
                    continue
                full = np.asarray(receiver.receiver_correlogram(g, cfg))
                cols = np.mod(np.asarray(start)[:, None] + np.arange(grid_search.grid_window_cells(cfg)), full.shape[1])
                ref = np.take_along_axis(full, cols, axis=1)
                vals, st = windows(s, start)
                assert np.array_equal(np.asarray(st), np.asarray(start))
                np.testing.assert_allclose(np.asarray(vals), ref, rtol=0, atol=1e-6 * np.abs(ref).max())
