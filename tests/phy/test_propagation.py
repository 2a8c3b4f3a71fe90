import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dpe5g.phy import deployment, propagation as scenario
from dpe5g.simulation import trial_draw
from dpe5g.studies import nlos as nlos_study


def test_packaged_deployment_has_the_papers_numbers():
    dep = deployment.tst()
    assert dep.n_bs == 26
    assert dep.area_m2 == pytest.approx(227_360.0, rel=1e-5)
    x0, y0, x1, y1 = dep.region
    assert x1 - x0 == pytest.approx(y1 - y0)  # a square
    assert np.all(dep.bs_xyz[:, 2] == 10.0) and np.all(dep.power_dbm == 24.0)
    assert dep.ue_height_m == 2.0 and len(dep.buildings) > 0
    assert all(x0 <= b[0] <= x1 and y0 <= b[1] <= y1 for b in dep.bs_xyz)


def test_los_probability_eq11():
    d = np.array([0.0, 10.0, 18.0, 36.0, 100.0])
    p = np.asarray(scenario.los_probability(d))
    assert np.all(p[:3] == 1.0)
    assert p[3] == pytest.approx(0.5 + 0.5 * np.exp(-1.0))
    assert p[4] == pytest.approx(0.18 + 0.82 * np.exp(-100 / 36))


@given(st.floats(18.0, 5000.0), st.floats(0.0, 100.0))
def test_los_probability_decreases_and_is_a_probability(d, dd):
    p1, p2 = np.asarray(scenario.los_probability(np.array([d, d + dd])))
    assert 0.0 <= p2 <= p1 <= 1.0


def test_umi_path_loss_values_and_breakpoint():
    # hand evaluation of TR 38.901 Table 7.4.1-1 at fc = 3 GHz, h_BS = 10 m, h_UT = 2 m (d'BP = 360 m)
    d3 = np.hypot(100.0, 8.0)
    pl_los = 32.4 + 21 * np.log10(d3) + 20 * np.log10(3.0)
    pl_nlos = max(pl_los, 35.3 * np.log10(d3) + 22.4 + 21.3 * np.log10(3.0) - 0.3 * 0.5)
    assert float(scenario.path_loss_umi_db(100.0, 10.0, 2.0, 3e9, True)) == pytest.approx(pl_los, abs=1e-9)
    assert float(scenario.path_loss_umi_db(100.0, 10.0, 2.0, 3e9, False)) == pytest.approx(pl_nlos, abs=1e-9)
    # PL1 and PL2 meet at the breakpoint (continuity of the LoS formula)
    below = float(scenario.path_loss_umi_db(360.0 - 1e-6, 10.0, 2.0, 3e9, True))
    above = float(scenario.path_loss_umi_db(360.0 + 1e-6, 10.0, 2.0, 3e9, True))
    assert above == pytest.approx(below, abs=1e-3)


@given(st.floats(10.0, 5000.0))
def test_nlos_path_loss_never_below_los(d):
    assert float(scenario.path_loss_umi_db(d, 10.0, 2.0, 3e9, False)) >= float(
        scenario.path_loss_umi_db(d, 10.0, 2.0, 3e9, True))


def test_link_budget():
    lb = scenario.LinkBudget()
    assert lb.noise_dbm == pytest.approx(-85.0)
    assert float(lb.snr_db(24.0, 100.0, 2.0)) == pytest.approx(24.0 - 100.0 - 2.0 + 85.0)
    assert float(lb.model_snr_db(10.0)) == pytest.approx(10.0 - 10 * np.log10(4096 * 30e3 / 100e6))
    with pytest.raises(ValueError, match="noise_figure_db"):
        scenario.LinkBudget(noise_figure_db=float("nan"))


def test_clock_bias_is_truncated():
    import jax

    b = np.asarray(scenario.clock_bias(jax.random.PRNGKey(0), 5e-9, 3.0, (20000,)))
    assert np.all(np.abs(b) <= 15e-9 + 1e-18)
    assert np.std(b) == pytest.approx(5e-9 * 0.986, rel=0.03)  # σ of a ±3σ-truncated Gaussian is 0.986 σ


def test_ue_outside_region_is_an_error():
    dep = deployment.tst()
    with pytest.raises(ValueError, match="inside the region"):
        dep.check_ue([600.0, 10.0])
    with pytest.raises(ValueError, match="finite"):
        dep.check_ue([np.nan, 10.0])


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("name, text, needle", [
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,24\n", "at least 3 base stations"),
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,ten,24\nC,0,100,10,24\n", "height_m must be"),
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,240\nC,0,100,10,24\n", "power_dbm must be"),
    ("d.csv", "id,x_m,y_m,power_dbm\nA,0,0,24\nB,100,0,24\nC,0,100,24\n", "missing height_m"),
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nA,100,0,10,24\nC,0,100,10,24\n", "duplicate id"),
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,nan,10,24\nC,0,100,10,24\n", "y_m must be"),
    ("d.json", "{not json", "not valid JSON"),
    ("d.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,24\nC,0,100,10,24\nD,50,50,10,24\nE,50,50,10,24\n",
     "base stations D and E are less than 0.5 m apart"),
    ("d.json", json.dumps({"base_stations": [{"x_m": 0, "y_m": 0, "height_m": 10, "power_dbm": 24}] * 3}),
     "less than 0.5 m apart"),
    ("d.json", json.dumps({"base_stations": [{"x_m": i * 50, "y_m": i * i * 10, "height_m": 10, "power_dbm": 24}
                                             for i in range(3)]}), "needs a region"),
    ("d.json", json.dumps({"base_stations": [{"x_m": i * 50, "y_m": i * i * 10, "height_m": 10, "power_dbm": 24}
                                             for i in range(3)],
                           "region": {"x_min_m": 0, "y_min_m": 0, "x_max_m": 60, "y_max_m": 60}}),
     "outside the region"),
    ("d.txt", "x", "must end in .json or .csv"),
    ("d.json", json.dumps({"base_stations": [{"x_m": i * 50, "y_m": 0, "height_m": 10, "power_dbm": 24}
                                             for i in range(4)],
                           "region": {"x_min_m": 0, "y_min_m": -10, "x_max_m": 200, "y_max_m": 10}}),
     "lie on one line"),
    ("d.json", json.dumps({"base_stations": [{"x_m": i * 50, "y_m": i * i * 10, "height_m": 10, "power_dbm": 24}
                                             for i in range(3)],
                           "region": {"x_min_m": 0, "y_min_m": -10, "x_max_m": 110, "y_max_m": 50},
                           "ue_region": {"x_min_m": 100, "y_min_m": -5, "x_max_m": 120, "y_max_m": 5}}),
     "ue_region .* must lie inside the region"),
    ("d.json", json.dumps({"base_stations": [{"x_m": i * 50, "y_m": i * i * 10, "height_m": 10, "power_dbm": 24}
                                             for i in range(3)],
                           "region": {"x_min_m": 0, "y_min_m": -10, "x_max_m": 110, "y_max_m": 50},
                           "ue_region": [0, 0, 5, 5]}), "ue_region must be an object"),
])
def test_malformed_deployment_files(tmp_path, name, text, needle):
    with pytest.raises(ValueError, match=needle):
        deployment.load_deployment(_write(tmp_path, name, text))


def test_csv_deployment_loads(tmp_path):
    p = _write(tmp_path, "mine.csv", "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,12,20\nC,0,100,10,24\n")
    dep = deployment.load_deployment(p)
    assert dep.bs_ids == ("A", "B", "C")
    assert dep.bs_xyz[1].tolist() == [100.0, 0.0, 12.0] and dep.power_dbm[1] == 20.0
    assert dep.region == (-10.0, -10.0, 110.0, 110.0)
    assert list(dep.nearest([90.0, 5.0], 2)) == [1, 0]


def test_packaged_rings_draw_the_ue_in_their_ue_region():
    """The rings of Chapter 3 ("ring", "ring-wide"): 8 BSs on a 150 m circle; every UE of the engine's draws lies in
    the deployment's UE square (10 m and 100 m wide), which check_ue enforces too; the "tst" layout draws over its
    whole region."""
    from dpe5g.simulation import draw
    from dpe5g.studies import paper

    for name, half in (("ring", 5.0), ("ring-wide", 50.0)):
        dep = deployment.named(name)
        assert dep.n_bs == 8 and np.allclose(np.linalg.norm(dep.bs_xyz[:, :2], axis=1), 150.0)
        assert dep.ue_bounds == (-half, -half, half, half)
        with pytest.raises(ValueError, match="inside the region"):
            dep.check_ue([half + 1.0, 0.0])
    assert deployment.tst().ue_bounds == deployment.tst().region
    e = paper.ring_window_experiments(n_trials=40)[1]
    links = draw.draw_links(e, 40)
    assert not links["los"].any()  # los_mode "all_nlos"
    ue = np.stack([draw.draw_fn(e, e.load_deployment())(trial_draw.trial_key(e.run.seed, t), t).ue_xyz for t in range(5)])
    assert np.all(np.abs(ue[:, :2]) <= 5.0) and np.ptp(ue[:, 0]) > 1.0


def test_free_space_links_are_one_unit_path():
    """los_mode "free_space": every link LoS, one path of unit power at the first tap, its phase drawn per link."""
    from dpe5g.simulation import draw
    from dpe5g.studies import paper

    e = paper.ml_toa_experiment(n_trials=2)
    d = draw.draw_fn(e, e.load_deployment())(trial_draw.trial_key(e.run.seed, 0), 0)
    g = np.asarray(d.gains)
    assert np.asarray(d.los).all()
    np.testing.assert_allclose(np.abs(g[:, 0]), 1.0, rtol=1e-12)
    assert np.all(g[:, 1:] == 0) and np.ptp(np.angle(g[:, 0])) > 0.1


def test_prs_reuse_plan_on_our_layout():
    dep = deployment.tst()
    res, ids = dep.prs_plan(6)
    assert sorted(set(res.tolist())) == list(range(6)) and len(set(res[:6].tolist())) == 6
    d = np.linalg.norm(dep.bs_xyz[:, None, :2] - dep.bs_xyz[None, :, :2], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert np.all(res[d.argmin(axis=1)] != res)  # nearest neighbours on different resources
    for r in range(6):  # PRS IDs distinct within a resource: 0, 1, ...
        assert sorted(ids[res == r].tolist()) == list(range(np.count_nonzero(res == r)))
    np.testing.assert_array_equal(dep.prs_plan(6)[0], res)  # deterministic


@given(st.integers(1, 12), st.sampled_from([2, 4, 6, 12]), st.integers(0, 1000))
def test_prs_reuse_plan_first_bss_distinct(n_bs, reuse, seed):
    xyz = np.random.default_rng(seed).uniform(0, 500, size=(n_bs, 3))
    res, ids = scenario.prs_plan(xyz, reuse)
    first = res[:reuse]
    assert len(set(first.tolist())) == len(first)
    assert np.all((res >= 0) & (res < reuse))


def test_prs_reuse_plan_bad_input():
    with pytest.raises(ValueError, match="reuse must be one of"):
        scenario.prs_plan(np.zeros((3, 3)), 5)
    with pytest.raises(ValueError, match="n_bs must be at most reuse × PRS IDs = 2 × 4096"):
        scenario.prs_plan(np.zeros((2 * 4096 + 1, 3)), 2)


def test_nlos_excess_delay_is_the_stated_log_normal():
    """scenario.nlos_excess_delay: 0 on LoS links; on NLoS links lg Δτ normal with the stated median and σ_lg
    (Kolmogorov–Smirnov against that law), and exactly the median when σ_lg = 0."""
    import jax
    from scipy import stats

    los = np.arange(20000) % 4 == 0
    d = np.asarray(scenario.nlos_excess_delay(jax.random.PRNGKey(3), los, 30e-9, 0.3))
    assert np.all(d[los] == 0.0)
    lg = np.log10(d[~los])
    assert stats.kstest(lg, stats.norm(np.log10(30e-9), 0.3).cdf).pvalue > 1e-3
    assert stats.kstest(lg, stats.norm(np.log10(30e-9) + 0.05, 0.3).cdf).pvalue < 1e-6  # the test can fail
    fixed = np.asarray(scenario.nlos_excess_delay(jax.random.PRNGKey(3), los, 30e-9, 0.0))
    assert np.all(fixed[~los] == 30e-9)
    with pytest.raises(ValueError, match=r"median_s must be finite and in \[0, 1e-06\] s"):
        scenario.nlos_excess_delay(jax.random.PRNGKey(3), los, 30.0, 0.3)
    with pytest.raises(ValueError, match="sigma_lg"):
        scenario.nlos_excess_delay(jax.random.PRNGKey(3), los, 30e-9, -1.0)


def test_nlos_excess_delay_delays_every_path_of_the_nlos_links_only():
    """With the excess delay on, a trial's draws are those of the same experiment without it, except that each NLoS
    link's spectrum is turned by Γ(Δτ) (all its paths Δτ late) and its tap delays grow by Δτ; at its default the
    setting leaves the experiment's key as it was."""
    import dataclasses

    import jax

    from dpe5g.phy import signal
    from dpe5g.simulation import draw, experiment
    from dpe5g.studies import paper

    base = paper.fig9_truth(n_trials=4)
    late = dataclasses.replace(base, scenario=dataclasses.replace(base.scenario, nlos_excess_median_s=30e-9,
                                                                  nlos_excess_sigma_lg=0.2))
    assert late.config_key() != base.config_key()
    as_before = dataclasses.replace(base, scenario=dataclasses.replace(base.scenario, nlos_excess_sigma_lg=0.0))
    assert as_before.config_key() == base.config_key()
    dep = base.load_deployment()
    key = trial_draw.trial_key(base.run.seed, 1)
    d0, d1 = draw.draw_fn(base, dep)(key, 1), draw.draw_fn(late, dep)(key, 1)
    los = np.asarray(d0.los)
    assert (~los).any() and np.array_equal(los, np.asarray(d1.los))
    excess = np.asarray(d1.delays_s - d0.delays_s)[:, 0]
    assert np.all(excess[los] == 0.0) and np.all(excess[~los] > 0.0)
    np.testing.assert_allclose(np.asarray(d1.y0), np.asarray(d0.y0 * signal.delay_phasor(excess)), atol=1e-12)
    np.testing.assert_array_equal(np.asarray(d1.noise), np.asarray(d0.noise))
    with pytest.raises(ValueError, match="nlos_excess_median_s must be in"):
        experiment.Scenario(nlos_excess_median_s=30.0)


def test_the_excess_delay_table_is_tr38901_table_7_6_9_1_and_its_quantiles_are_the_log_normals():
    """TR 38.901 Table 7.6.9-1's outdoor rows as transcribed (lg Δτ mean, σ), UMi the scenario's row; the quantile
    of the drawn law matches the empirical one of scenario.nlos_excess_delay."""
    import jax

    rows = {k: (r.mu_lg, r.sigma_lg) for k, r in scenario.TR38901_EXCESS_DELAY.items()}
    assert rows == {"UMi": (-7.5, 0.5), "UMa": (-7.4, 0.2), "RMa": (-8.33, 0.26), "SMa": (-7.702, 0.4)}
    umi = scenario.TR38901_EXCESS_DELAY[scenario.NLOS_EXCESS_ROW]
    assert scenario.NLOS_EXCESS_ROW == "UMi" and umi.median_s == pytest.approx(31.62e-9, rel=1e-3)
    assert nlos_study.NLOS_EXCESS_SIGMA_LG == umi.sigma_lg and umi.median_s in nlos_study.NLOS_EXCESS_MEDIANS_S
    d = np.asarray(scenario.nlos_excess_delay(jax.random.PRNGKey(0), np.zeros(200000, bool), umi.median_s,
                                              umi.sigma_lg))
    for q in (0.1, 0.5, 0.99):
        assert umi.quantile_s(q) == pytest.approx(np.quantile(d, q), rel=0.02), q
    assert umi.quantile_s(0.99) == pytest.approx(10 ** (-7.5 + 0.5 * 2.3263479), rel=1e-6)
    with pytest.raises(ValueError, match="q must be"):
        umi.quantile_s(1.0)


def test_the_clock_nlos_window_adds_the_excess_delays_99th_percentile_to_the_clock_models():
    """Receiver clock_window "clock_nlos": the c δt window ± (3 σ c + c Δτ₉₉) of the scenario's law, in boxes of
    about box_m; "clock" keeps ± 3 σ c; the default leaves every stored key as it was; refused when centred on the
    truth."""
    from dpe5g.simulation import experiment
    from dpe5g.phy.nr import C

    wide = nlos_study.fig10_clock_nlos(10)["two_of_four"]
    plain = nlos_study.fig10_nlos_excess(nlos_study.UMI.median_s, 10)[("two_of_four", "otdoa")]
    clock = 3 * 5e-9 * C
    assert plain.receiver_search().bias_half_width_m == pytest.approx(clock)
    s = wide.receiver_search()
    assert s.bias_half_width_m == pytest.approx(clock + C * nlos_study.UMI.quantile_s(0.99))
    assert s.bias_boxes == min(64, int(np.ceil(2 * s.bias_half_width_m / s.box_m)))
    assert wide.replace(name=plain.run.name, clock_window="clock") == plain
    assert plain.config_key() == plain.replace(clock_window="clock").config_key()
    assert "clock_window" not in json.dumps(plain.to_dict()) or plain.receiver.clock_window == "clock"
    with pytest.raises(ValueError, match="clock_window must be one of"):
        experiment.Receiver(clock_window="wide")
    with pytest.raises(ValueError, match="centring 'truth' searches its own"):
        experiment.Receiver(clock_window="clock_nlos")


def test_nearest_two_los_and_the_snr_offset_change_only_what_they_say():
    """los_mode "nearest_two_los": the two nearest of the four links LoS, the two farther NLoS, every trial;
    snr_offset_db: every link's SNR moved by exactly that many dB, the other draws unchanged."""
    from dpe5g.simulation import draw
    from dpe5g.studies import paper

    base = paper.fig10(4)[("two_of_four", "truth")]
    near = nlos_study.fig10_nearest_los(4)["truth"]
    low = nlos_study.fig10_snr_offset(-12.0, 4)["truth"]
    dep = base.load_deployment()
    for t in range(3):
        key = trial_draw.trial_key(base.run.seed, t)
        d0, dn, dl = (draw.draw_fn(e, dep)(key, t) for e in (base, near, low))
        assert np.array_equal(np.asarray(dn.los), [True, True, False, False])
        np.testing.assert_array_equal(np.asarray(dn.ue_xyz), np.asarray(d0.ue_xyz))
        np.testing.assert_allclose(np.asarray(dl.link_snr_db - d0.link_snr_db), -12.0, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(dl.y0), np.asarray(d0.y0))
    with pytest.raises(ValueError, match="snr_offset_db applies to snr_mode 'link_budget' only"):
        paper.fig9_truth(4).replace(snr_offset_db=-6.0)
