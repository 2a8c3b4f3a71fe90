"""The ray-traced city (issue 45): the stored paths re-traced in part, the traced LoS path against free space, the
traced channel source through the one signal model, its population and link order, and its bad input."""

import os

import numpy as np
import pytest

from dpe5g import city_draw, city_paths, city_study, city_trace, ray_tracer, signal, trial_draw
from dpe5g.experiment import Experiment
from dpe5g.nr import C

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
    """The check above can fail: a stored power moved by 3 dB, or a first path by 1 ns, is reported."""
    k = int(np.argmax(city.power_db))
    power, excess = city.power_db.copy(), city.excess_s.copy()
    power[k] += 3.0
    excess[k, 0] += 1e-9
    changed = city_paths.TracedCity(**{**city.__dict__, "power_db": power, "excess_s": excess})
    found = city_paths.compare_links(changed, *retraced)
    assert len(found) == 1 and "power 3 dB, first-path delay 1 ns off" in found[0], found


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
    draw = city_draw.draw_fn(e, dep)
    _, links = city_draw.population(e)
    heard = city_draw.heard_links(e, city, dep)
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
        assert np.all(np.asarray(d.link_snr_db) >= city_draw.DETECTION_SNR_DB)
    assert np.all((table[links.ue_index] >= 0).sum(axis=1) >= 4)
    assert not np.any(((table >= 0).sum(axis=1) >= 4)[np.setdiff1d(np.arange(city.n_ue), links.ue_index)])


def test_traced_channel_bad_input():
    with pytest.raises(ValueError, match="channel"):
        Experiment.build(name="x", channel="raytraced")
    with pytest.raises(ValueError, match="prs_reuse 0"):
        Experiment.build(name="x", channel="traced", deployment=city_study.CITY, prs_reuse=6, snr_mode="link_budget")
    e = city_study.city_fig10(8, "truth", n_trials=100_000)
    with pytest.raises(ValueError, match="n_trials must be at most"):
        city_draw.population(e)


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
    _, links = city_draw.population(city_study.city_fig10(city_study.CITY_M[0], "otdoa", n_trials=1))
    assert int(view["ue"]) == links.ue_index[0] and np.array_equal(view["ue_bs"], links.bs_index[0])
    lines = np.split(view["points"], view["start"][1:-1])
    assert all(np.allclose(line[0], city.bs_xyz[links.bs_index[0][b]]) and np.allclose(line[-1], city.ue_xyz[
        links.ue_index[0]]) for line, b in zip(lines, view["bs"]))
