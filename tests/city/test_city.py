"""The ray-traced city (issue 45): the stored paths re-traced in part, the traced LoS path against free space, the
traced channel source through the one signal model, its population and link order, and its bad input."""

import glob
import inspect
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from dpe5g.common.errors import Failure
from dpe5g.phy import signal
from dpe5g.receivers import otdoa
from dpe5g.city import dataset as city_paths, ray_tracer, trace as city_trace
from dpe5g.simulation import traced_draw, trial_draw
from dpe5g.studies import city as city_study
from dpe5g.simulation.experiment import Experiment
from dpe5g.phy.nr import C

#: UEs re-traced per run (each against every BS), drawn from the run's verification seed
RETRACE_UES = 3


@pytest.fixture(scope="module")
def city():
    return city_paths.load_city(city_study.CITY)


@pytest.fixture(scope="module")
def retraced(city):
    """RETRACE_UES UEs drawn from the run's verification seed, and the UE of the strongest stored link (for the
    self-test below), traced again in one call of the solver."""
    seed = int(os.environ["DPE5G_VERIFY_SEED"])
    ues = np.random.default_rng([seed, 45]).choice(city.n_ue, RETRACE_UES, replace=False)
    ues = np.unique(np.append(ues, city.link_ue[np.argmax(city.power_db)]))
    return ues, city_paths.retrace_links(city, ues)


def test_a_sample_of_the_stored_links_is_what_sionna_traces_today(city, retraced):
    ues, new = retraced
    found = city_paths.compare_links(city, ues, new)
    assert not found, f"UEs {ues.tolist()} re-traced differ from the store:\n" + "\n".join(found[:20])


def test_compare_links_finds_a_changed_link(city, retraced):
    """The check above can fail: a stored power moved by 3 dB, a first path by 1 ns or its gain by 0.1 dB, a LoS state
    flipped, or every link's power moved by 0.2 dB, is reported."""
    k = int(np.argmax(city.power_db))
    base = set(city_paths.compare_links(city, *retraced))

    def found(**changes):
        changed = city_paths.TracedCity(**{**city.__dict__, **changes})
        return [line for line in city_paths.compare_links(changed, *retraced) if line not in base]

    power, excess, gains, los = city.power_db.copy(), city.excess_s.copy(), city.gains.copy(), city.los.copy()
    power[k] += 3.0
    excess[k, 0] += 1e-9
    new = found(power_db=power, excess_s=excess)
    assert len(new) == 1 and "power 3 dB, first-path delay 1 ns off" in new[0], new
    gains[k, 0] *= 10 ** (0.1 / 20)
    assert len(new := found(gains=gains)) == 1 and "first-path gain 0.1 dB off" in new[0], new
    los[k] = not los[k]
    assert len(new := found(los=los)) == 1 and f"(stored {not city.los[k]})" in new[0], new
    assert any("median power difference is 0.2 dB" in line for line in found(power_db=city.power_db + 0.2))


def test_the_traced_los_path_is_free_space(city):
    """Every LoS link's first path has the Friis gain (λ/4πd)² of its straight line and arrives at d/c."""
    assert city_paths.path_gain_check(city) < 0.01
    assert np.max(np.abs(city.first_excess_s()[city.los])) < 1e-12


def test_the_city_is_the_stated_deployment(city):
    spec = city_trace.CitySpec(**city.spec)
    x0, y0, x1, y1 = city.region
    assert city.n_bs == spec.n_bs == 26 and city.n_ue == spec.n_ue
    assert abs((x1 - x0) * (y1 - y0) - 227_360) < 1
    assert spec.ue_height_m == 2.0 and np.all(city.bs_xyz[:, 2] == 10.0) and np.all(city.ue_xyz[:, 2] == 2.0)
    inside = lambda p: (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
    assert inside(city.bs_xyz).all() and inside(city.ue_xyz).all()
    assert np.all(city.kept_db <= 1e-4) and np.all(city.n_paths >= 1)  # float32 sums: kept ≤ all


def test_the_traced_source_runs_the_one_signal_model(city):
    """A trial's noise-free spectrum is the traced paths through ``signal.received_noiseless_direct`` (the time-domain
    synthesis of eqs. (3)–(5)), and its links are the strongest the UE hears, at the detection SNR or above."""
    e = city_study.city_fig10(4, "truth", n_trials=5)
    dep = e.load_deployment()
    draw = traced_draw.draw_fn(e, dep)
    _, links = traced_draw.population(e)
    heard = traced_draw.heard_links(e, city, dep)
    table = np.where(heard[city.link_table()] & (city.link_table() >= 0), city.link_table(), -1)
    toa = lambda d: np.linalg.norm(np.asarray(d.bs_xyz) - np.asarray(d.ue_xyz), axis=1) / C
    for t in (0, 4):
        d = draw(trial_draw.trial_key(e.run.seed, t), t)
        i = 3 * (t > 0)  # the strongest link of one trial, the weakest of another (direct synthesis is O(N²) a path)
        nz = np.asarray(d.gains[i]) != 0
        direct = signal.received_noiseless_direct(d.prs[i:i + 1], np.asarray(d.gains)[i:i + 1, nz],
                                                  np.asarray(d.delays_s)[i:i + 1, nz], toa(d)[i:i + 1], d.clock_bias_s)
        np.testing.assert_allclose(np.asarray(signal.ofdm_symbol(d.y0))[i:i + 1], direct, atol=1e-9)
        assert np.all(np.diff(links.power_db[t]) <= 0)
        row = table[links.ue_index[t]]
        assert np.all(row[np.asarray(d.bs_index)] >= 0)
        assert np.isclose(links.power_db[t, 0], city.power_db[row[row >= 0]].max())
        assert np.all(np.asarray(d.link_snr_db) >= traced_draw.DETECTION_SNR_DB)
    assert np.all((table[links.ue_index] >= 0).sum(axis=1) >= 4)
    assert not np.any(((table >= 0).sum(axis=1) >= 4)[np.setdiff1d(np.arange(city.n_ue), links.ue_index)])


def test_traced_channel_bad_input():
    with pytest.raises(ValueError, match="channel"):
        Experiment.build(name="x", channel="raytraced")
    with pytest.raises(ValueError, match="prs_reuse 0"):
        Experiment.build(name="x", channel="traced", deployment=city_study.CITY, prs_reuse=6, snr_mode="link_budget")
    e = city_study.city_fig10(8, "truth", n_trials=100_000)
    with pytest.raises(ValueError, match="n_trials must be at most"):
        traced_draw.population(e)


def test_a_missing_llvm_is_one_line_naming_the_package(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(ray_tracer, "LLVM_GLOBS", ("/nonexistent/libLLVM*.so",))
    with pytest.raises(RuntimeError, match="apt-get install libllvm19"):
        ray_tracer.llvm_library()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/nonexistent/libLLVM.so.19.1")
    with pytest.raises(RuntimeError, match="no such file"):
        ray_tracer.llvm_library()


def test_the_stored_city_is_current_so_make_reproduce_does_not_trace_it_again(city):
    spec = city_trace.CitySpec().to_dict()
    assert city.spec == spec, "CitySpec changed since the city was traced: run make reproduce (dpe5g trace)"
    assert city_paths.is_current(city.name, spec, city_trace.code_digest()), \
        "the tracing code changed since the city was traced: run make reproduce (dpe5g trace)"
    assert not city_paths.is_current(city.name, {**spec, "n_ue": spec["n_ue"] + 1}, city_trace.code_digest())
    assert not city_paths.is_current(city.name, spec, "0" * 16)


def test_the_3d_view_is_of_the_first_trial(city):
    view = city_paths.load_view(city.name)
    _, links = traced_draw.population(city_study.city_fig10(city_study.CITY_M[0], "otdoa", n_trials=1))
    assert int(view["ue"]) == links.ue_index[0] and np.array_equal(view["ue_bs"], links.bs_index[0])
    lines = np.split(view["points"], view["start"][1:-1])
    assert all(np.allclose(line[0], city.bs_xyz[links.bs_index[0][b]]) and np.allclose(line[-1], city.ue_xyz[
        links.ue_index[0]]) for line, b in zip(lines, view["bs"]))


def tiny_city():
    """Three UEs, three BSs, seven links of two kept paths: lg Δτ of the NLoS links' earliest paths −8, −7 (UE 0),
    −6, −10 (UE 1), −8 (UE 2); UE 0's first NLoS link's earliest path is 20 dB below its strongest (lg −7), the
    others' within 6 dB of it or alone.  2-D distances 0 or 36 m."""
    ns = 1e-9
    rows = [  # UE, BS, LoS, (Δτ, |a|) of the two kept paths (|a| 0: no path)
        (0, 0, True, (0.0, 1.0), (50 * ns, 0.5)),
        (0, 1, False, (10 * ns, 0.1), (100 * ns, 1.0)),
        (0, 2, False, (100 * ns, 1.0), (1000 * ns, 0.5)),
        (1, 0, False, (1000 * ns, 1.0), (0.0, 0.0)),
        (1, 1, False, (0.1 * ns, 0.5), (10 * ns, 1.0)),
        (2, 0, True, (0.0, 1.0), (0.0, 0.0)),
        (2, 2, False, (10 * ns, 1.0), (0.0, 0.0))]
    g = np.array([[r[3][1], r[4][1]] for r in rows], np.complex64)
    p = (np.abs(g) ** 2).sum(axis=1)
    return city_paths.TracedCity(
        name="tiny", spec={}, region=np.array([0.0, 0.0, 36.0, 36.0]),
        bs_xyz=np.array([[0.0, 0.0, 10.0], [36.0, 0.0, 10.0], [0.0, 36.0, 10.0]]),
        ue_xyz=np.array([[0.0, 0.0, 2.0], [36.0, 0.0, 2.0], [0.0, 36.0, 2.0]]),
        link_ue=np.array([r[0] for r in rows]), link_bs=np.array([r[1] for r in rows]),
        excess_s=np.array([[r[3][0], r[4][0]] for r in rows], np.float32), gains=g,
        n_paths=(np.abs(g) > 0).sum(axis=1), los=np.array([r[2] for r in rows]),
        power_db=(10 * np.log10(p)).astype(np.float32), kept_db=np.zeros(len(rows), np.float32))


def test_excess_fit_on_a_tiny_city_is_the_hand_computed_one():
    """``excess_fit`` on hand-made links: the earliest path and the first path within the detector's threshold, every
    link or a subset given as a mask or as rows (the LoS among them left out), against values computed by hand."""
    tiny = tiny_city()
    fit = city_study.excess_fit(tiny, n_boot=50)
    lg = np.array([-8.0, -7.0, -6.0, -10.0, -8.0])
    assert (fit.n_links, fit.n_ues, fit.threshold_db) == (5, 3, None)
    assert np.isclose(fit.mean_lg, -7.8, atol=1e-6) and np.isclose(fit.std_lg, np.sqrt(1.76), atol=1e-6)
    assert np.isclose(fit.median_s, 1e-8, rtol=1e-6) and fit.below_1ns == 0.2
    assert np.isclose(fit.ks_p, stats.kstest(lg, stats.norm(-7.5, 0.5).cdf).pvalue, rtol=1e-5)
    # UEs 0 and 1 (UE 2 has one NLoS link): means −7.5, −8; MSB 0.25, MSW 4.25, k₀ 2
    assert np.isclose(fit.icc, (0.25 - 4.25) / (0.25 + 4.25), atol=1e-6)
    assert -20 < city_study.FIRST_PATH_THRESHOLD_DB < -6  # the hand values below: 20 dB down is out, 6 dB in
    thr = city_study.excess_fit(tiny, threshold_db=city_study.FIRST_PATH_THRESHOLD_DB, n_boot=50)
    assert thr.threshold_db == city_study.FIRST_PATH_THRESHOLD_DB
    assert np.isclose(thr.mean_lg, -7.6, atol=1e-6)  # UE 0's first link: −8 → −7
    assert np.isclose(thr.median_s, 1e-7, rtol=1e-6) and thr.below_1ns == 0.2
    assert city_study.excess_fit(tiny, np.ones(7, bool), n_boot=50) == fit
    sub = city_study.excess_fit(tiny, np.array([4, 0, 3, 1, 2]), n_boot=50)  # UEs 0 and 1, a LoS link among them
    assert sub == city_study.excess_fit(tiny, np.arange(7) < 5, n_boot=50)
    assert (sub.n_links, sub.n_ues) == (4, 2) and np.isclose(sub.mean_lg, -7.75, atol=1e-6)
    with pytest.raises(ValueError, match="no NLoS link"):
        city_study.excess_fit(tiny, [0, 5])
    with pytest.raises(ValueError, match="shape"):
        city_study.excess_fit(tiny, np.ones(6, bool))
    with pytest.raises(ValueError, match="link indices"):
        city_study.excess_fit(tiny, [1, 7])
    with pytest.raises(ValueError, match="threshold_db"):
        city_study.excess_fit(tiny, threshold_db=3.0)
    shares = city_study.los_shares(tiny, {"all": None, "nlos": ~tiny.los})
    p36 = 0.5 + 0.5 * np.exp(-1.0)  # eq. (11) at 36 m: 18/36 + (1 − 18/36) e^(−1)
    assert shares["all"]["n_links"] == 7 and np.isclose(shares["all"]["share"], 2 / 7)
    assert np.isclose(shares["all"]["eq11"], (3 + 4 * p36) / 7)
    assert shares["nlos"]["share"] == 0 and np.isclose(shares["nlos"]["eq11"], (1 + 1 + 3 * p36) / 5)


def test_the_first_path_threshold_is_the_detectors_and_never_earlier_than_the_earliest_path(city):
    """The threshold is the first-path OTDoA detector's default; the first path it picks is the earliest kept path
    within it of the link's strongest, so never earlier than the earliest path and never later than the strongest."""
    assert city_study.FIRST_PATH_THRESHOLD_DB == inspect.signature(otdoa.toa).parameters["threshold_db"].default
    earliest, first = city.first_excess_s(), city.first_excess_s(city_study.FIRST_PATH_THRESHOLD_DB)
    p = np.abs(city.gains.astype(complex)) ** 2
    strong = p >= p.max(axis=1, keepdims=True) * 10 ** (city_study.FIRST_PATH_THRESHOLD_DB / 10)
    tau = city.excess_s.astype(float)
    assert np.all(first >= earliest)
    assert np.all(first <= tau[np.arange(len(p)), np.argmax(p, axis=1)])
    assert np.all(np.any((tau == first[:, None]) & strong, axis=1))  # it is a path within the threshold ...
    assert not np.any((tau < first[:, None]) & strong & (p > 0))  # ... and no earlier path is
    assert np.mean(first > earliest) > 0.1  # the threshold changes many links' first paths
    assert np.array_equal(city.first_excess_s(-300.0), earliest)
    assert np.array_equal(first[city.los], earliest[city.los])  # every LoS link's direct path is within it


def test_the_trials_links_are_heard_links_are_traced_links(city):
    """``link_populations``: the trial links (each trial's UE with its four strongest heard links) within the heard
    links within the traced links, their LoS states the trials'; another experiment's run is refused."""
    e = city_study.city_fig10(city_study.CITY_M[0], "otdoa")
    _, links = traced_draw.population(e)
    t = e.run.n_trials
    res = SimpleNamespace(ue_xyz=city.ue_xyz[links.ue_index[:t]], bs_index=links.bs_index[:t], los=links.los[:t])
    pops = city_study.link_populations(city, e, res)
    assert tuple(pops) == city_study.POPULATIONS
    assert pops["all"].all() and np.all(pops["heard"] <= pops["all"]) and np.all(pops["trial"] <= pops["heard"])
    assert pops["trial"].sum() == t * city_study.CITY_M[0] < pops["heard"].sum() < pops["all"].sum()
    assert np.isclose(city_study.los_shares(city, pops)["trial"]["share"], res.los.mean())
    nlos = {k: v & ~city.los for k, v in pops.items()}
    assert 0 < nlos["trial"].sum() < nlos["heard"].sum() < nlos["all"].sum()
    with pytest.raises(ValueError, match="not a run of"):
        city_study.link_populations(city, e, SimpleNamespace(**{**res.__dict__, "bs_index": res.bs_index[::-1]}))


LLVM15 = sorted(glob.glob("/usr/lib/*/libLLVM-15.so*"))


@pytest.mark.skipif(not LLVM15, reason="no libLLVM 15 on this machine (Debian's default llvm)")
def test_an_unusable_llvm_is_refused_before_it_can_abort(tmp_path, monkeypatch):
    """LLVM 15 (Debian's default) aborts Dr.Jit's CPU backend with SIGABRT: refused by its version, and, named without
    one, by the probe in a subprocess; a file that is no library likewise: each an ``errors.Failure`` of one line."""
    from dpe5g.common.errors import Failure

    ray_tracer.check_llvm.cache_clear()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", LLVM15[0])
    with pytest.raises(Failure, match="LLVM 15, but Dr.Jit's CPU backend needs LLVM 16 or later: apt-get install"):
        ray_tracer.llvm_library()
    (tmp_path / "libLLVM.so").symlink_to(LLVM15[0])
    with pytest.raises(Failure, match="cannot run on it .*apt-get install libllvm19"):
        ray_tracer.check_llvm(str(tmp_path / "libLLVM.so"))
    (tmp_path / "junk.so").write_text("not a library\n")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "junk.so"))
    with pytest.raises(Failure, match="junk.so: Dr.Jit's CPU backend cannot run on it"):
        ray_tracer.llvm_library()


def test_trace_without_its_stack_is_one_line_and_nothing_else_needs_it():
    """Without sionna-rt, ``dpe5g trace`` ends in one line naming the package and exit code 1; the stored city, its
    traced channel source and its studies load without it."""
    block = "import sys; sys.modules.update(sionna=None, mitsuba=None, drjit=None); "
    r = subprocess.run([sys.executable, "-c", block + "from dpe5g.cli.main import main; raise SystemExit(main(['trace']))"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
    assert "ray tracing needs sionna-rt" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-c", block + "from dpe5g.city import dataset; from dpe5g.simulation import "
                        "traced_draw; from dpe5g.studies import city; c = dataset.load_city(city.CITY); "
                        "traced_draw.population(city.city_fig10(4, 'otdoa', n_trials=2)); print(c.n_ue)"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "5000", r.stderr


def test_a_sionna_without_its_ray_tracer_is_one_line(tmp_path, monkeypatch):
    """A ``sionna`` package without ``sionna.rt`` (another package of that name): refused before any import, naming
    sionna-rt."""
    import importlib.machinery

    real = importlib.util.find_spec
    bare = importlib.machinery.ModuleSpec("sionna", None, is_package=True)
    bare.submodule_search_locations = [str(tmp_path)]
    monkeypatch.setattr(ray_tracer.importlib.util, "find_spec", lambda name: bare if name == "sionna" else real(name))
    with pytest.raises(Failure, match=r"ray tracing needs sionna-rt \(its module sionna.rt is missing\)"):
        ray_tracer.check_packages()


def test_the_backend_is_chosen_once_per_process_and_a_missing_gpu_is_one_line(capsys):
    """``ray_tracer.use_backend``: "llvm" traces on the CPU's variant, and any other backend once a process traces on
    one is an ``errors.Failure`` of one line; "cuda" where Dr.Jit finds no GPU likewise, naming the CPU's backend;
    ``dpe5g trace --backend`` takes only the three.  (In fresh processes: a process chooses its backend once.)"""
    probe = ("from dpe5g.city import ray_tracer\nfrom dpe5g.common.errors import Failure\n"
             "try:\n    print(ray_tracer.use_backend(B))\nexcept Failure as err:\n    print('refused:', err)\n"
             "try:\n    ray_tracer.use_backend('cuda' if B == 'llvm' else 'llvm')\n"
             "except Failure as err:\n    print('refused:', err)\n")
    r = subprocess.run([sys.executable, "-c", "B = 'llvm'\n" + probe], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [ray_tracer.BACKENDS["llvm"], "refused: backend cuda: this process already traces "
                                     f"on {ray_tracer.BACKENDS['llvm']} (the backend is chosen once per process, "
                                     "before anything is traced)"]
    r = subprocess.run([sys.executable, "-c", "B = 'cuda'\n" + probe], capture_output=True, text=True, timeout=300)
    first = r.stdout.splitlines()[0]
    if first == ray_tracer.BACKENDS["cuda"]:  # (a machine with a GPU: nothing to refuse)
        pytest.skip("Dr.Jit found a CUDA device here")
    assert first.startswith("refused: backend cuda: Dr.Jit finds no CUDA device here (") and first.endswith(
        "); backend llvm traces on the CPU"), r.stdout
    with pytest.raises(ValueError, match="backend must be 'auto' or one of llvm, cuda, got 'gpu'"):
        ray_tracer.use_backend("gpu")
    from dpe5g.cli import main as cli

    assert cli.main(["trace", "--backend", "gpu"]) == 2
    assert "argument --backend: invalid choice: 'gpu'" in capsys.readouterr().err
