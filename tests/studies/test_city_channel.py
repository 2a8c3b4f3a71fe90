"""The traced links' delay spread and K-factor against TR 38.901's UMi (``city_channel``), and the genie first path
that splits the city's error into NLoS bias and the rest (``city_errors``): each on hand-made input whose answer is
known, the genie also on the stored city trials, and bad input."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from dpe5g.phy import channel
from dpe5g.receivers import otdoa
from dpe5g.city import dataset as city_paths
from dpe5g.simulation import engine
from dpe5g.studies import city as city_study, city_channel, city_errors
from dpe5g.phy.nr import C

#: a LoS link of two paths: the direct one (power 1, at d/c) and one 40 ns later a quarter as strong, padded to K = 3
TWO_PATHS = (np.array([[0.0, 40e-9, 0.0]]), np.array([[1.0, 0.5j, 0.0]]))


def test_delay_spread_and_k_factor_of_a_two_path_link_by_hand():
    """Powers 1 and 1/4 at 0 and 40 ns: weights 0.8 and 0.2, mean delay 8 ns, second moment 320 ns², so DS = √(320 −
    64) ns = 16 ns; K = 10 lg(1 / 0.25) = 6.02 dB.  An empty padding path changes neither, a common delay not DS."""
    tau, a = TWO_PATHS
    ds = city_channel.delay_spread_s(tau, a)
    assert ds.shape == (1,) and abs(ds[0] - 16e-9) < 1e-18
    assert abs(ds[0] - channel.rms_delay_spread(tau[0, :2], np.abs(a[0, :2]) ** 2)) < 1e-18
    assert abs(city_channel.delay_spread_s(tau + 7e-9, a)[0] - 16e-9) < 1e-18
    k = city_channel.k_factor_db(a, np.array([True]))
    assert abs(k[0] - 10 * math.log10(4.0)) < 1e-12
    assert np.isnan(city_channel.k_factor_db(a, np.array([False]))[0])  # no K on an NLoS link
    one = np.array([[2.0, 0.0, 0.0]])
    assert city_channel.delay_spread_s(tau, one)[0] == 0.0
    assert city_channel.k_factor_db(one, np.array([True]))[0] == math.inf


def test_umi_rows_are_table_7_5_6_at_the_carrier():
    """TR 38.901 Table 7.5-6 Part-1, UMi-Street Canyon, transcribed a second time: at 3 GHz lg(1 + fc) = lg 4; below
    2 GHz the entries take fc = 2 GHz."""
    u = city_channel.umi_lsp(3e9)
    lg4 = math.log10(4.0)
    assert u.fc_ghz == 3.0
    assert abs(u.lgds_mu_los - (-0.24 * lg4 - 7.14)) < 1e-12 and u.lgds_sigma_los == 0.38
    assert abs(u.lgds_mu_nlos - (-0.24 * lg4 - 6.83)) < 1e-12
    assert abs(u.lgds_sigma_nlos - (0.16 * lg4 + 0.28)) < 1e-12
    assert (u.k_mu_db, u.k_sigma_db) == (9.0, 5.0)
    assert city_channel.umi_lsp(1e9) == city_channel.umi_lsp(2e9) != city_channel.umi_lsp(2.5e9)


def test_lsp_summary_of_a_hand_made_city():
    """Three links: the two-path LoS link, an NLoS link of two equal paths 20 ns apart (DS 10 ns) and an NLoS link of
    one path (DS 0, left out of lg DS)."""
    tau = np.array([[0.0, 40e-9], [5e-9, 25e-9], [30e-9, 0.0]], dtype=np.float32)
    a = np.array([[1.0, 0.5j], [0.3, -0.3], [0.1, 0.0]], dtype=np.complex64)
    n = np.arange(3)
    city = city_paths.TracedCity(
        name="hand", spec={"fc_hz": 3e9, "n_paths": 2}, region=np.array([0.0, 0.0, 1.0, 1.0]),
        bs_xyz=np.zeros((3, 3)), ue_xyz=np.ones((1, 3)), link_ue=np.zeros(3, int), link_bs=n, excess_s=tau, gains=a,
        n_paths=np.array([2, 2, 1]), los=np.array([True, False, False]), power_db=np.zeros(3, np.float32),
        kept_db=np.zeros(3, np.float32))
    s = city_channel.lsp_summary(city)
    assert s.n_links == 3 and s.umi == city_channel.umi_lsp(3e9)
    assert s.lgds_los.n == 1 and abs(s.lgds_los.median - math.log10(16e-9)) < 1e-6
    assert (s.lgds_nlos.n, s.lgds_nlos.n_left_out) == (1, 1) and abs(s.lgds_nlos.median - math.log10(10e-9)) < 1e-6
    assert s.k_db.n == 1 and abs(s.k_db.mean - 10 * math.log10(4.0)) < 1e-5 and s.k_db.std == 0.0
    assert city_channel.lsp_summary(city, [1, 2]).lgds_los.n == 0


def _trials(n, m, seed):
    """n trials of m BSs round a UE at 2 m: the noise-free ToAs d/c + δt, and NLoS excess delays on the last link."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0.0, 2 * np.pi, m, endpoint=False)[None] + rng.uniform(0, 0.5, (n, m))
    r = rng.uniform(60.0, 200.0, (n, m))
    bs = np.stack([r * np.cos(ang), r * np.sin(ang), np.full((n, m), 10.0)], axis=-1)
    ue = np.concatenate([rng.uniform(-20.0, 20.0, (n, 2)), np.full((n, 1), 2.0)], axis=-1)
    toa = (np.linalg.norm(ue[:, None] - bs, axis=-1) + rng.normal(0.0, 1.5, (n, 1))) / C
    dt = np.zeros((n, m))
    dt[:, -1] = rng.uniform(20e-9, 200e-9, n)
    return bs, toa, dt, ue


def test_the_genie_gives_the_noise_free_fix_back():
    """ToAs late by a known excess on one link: the fixes from them are off by metres, the genie's (the excess
    subtracted) are the truth, for the OTDoA fix and the ToA fit in a 4.5 m clock window alike."""
    bs, toa, dt, ue = _trials(20, 4, 7)
    raw, genie = city_errors.genie_fixes(bs, toa + dt, dt, ue[:, 2], bias_half_m=4.5, half_width_m=30.0)
    for xy in (genie.otdoa_xy, genie.fit_xy):
        assert np.max(np.linalg.norm(xy - ue[:, :2], axis=-1)) < 1e-5
    assert genie.otdoa_ok.all()
    assert np.median(np.linalg.norm(raw.otdoa_xy - ue[:, :2], axis=-1)) > 1.0


@pytest.fixture(scope="module")
def stored():
    """The city, its honest experiment with M = 4 and the first 60 of its stored trials."""
    city = city_paths.load_city(city_study.CITY)
    e = city_study.city_fig10(city_study.CITY_M[0], "otdoa")
    res = engine.run(e, progress=False)
    keep = ("ue_xyz", "bs_index", "los", "otdoa_toa_s", "otdoa_xyz", "otdoa_error_m", "error_m", "est_xyz",
            "est_bias_s", "clock_bias_s")
    return city, e, SimpleNamespace(**{k: np.asarray(getattr(res, k))[:60] for k in keep})


def test_the_genie_on_the_stored_trials(stored):
    """The fixes recomputed from the stored ToAs are the engine's; on a trial whose links are all LoS the genie
    changes nothing; with the detector's threshold it lowers the median error."""
    city, e, res = stored
    g = city_errors.genie_split(city, e, res, city_study.FIRST_PATH_THRESHOLD_DB)
    assert g.refix_gap_m <= otdoa.POSITION_ATOL_M
    assert np.allclose(g.otdoa_m, res.otdoa_error_m[:, 0, 0, 0], rtol=0, atol=otdoa.POSITION_ATOL_M)
    los = g.n_nlos == 0
    assert los.any() and np.allclose(g.genie_otdoa_m[los], g.otdoa_m[los], rtol=0, atol=1e-3)
    assert np.all(g.excess_s[res.los] < 1e-12) and np.all(g.excess_s[~res.los] > 0)
    assert np.median(g.genie_otdoa_m) < np.median(g.otdoa_m)
    lt = city_errors.los_trials(city, e, res)
    assert np.array_equal(lt.trial, np.nonzero(los)[0]) and lt.k_db.shape == lt.ds_s.shape == (los.sum(), 4)
    assert np.all(np.abs(lt.otdoa_range_m) < 3.0)  # the first-path ToAs of LoS links are right to a few decimetres


def test_bad_input_is_refused_naming_the_parameter(stored):
    city, e, res = stored
    tau, a = TWO_PATHS
    for fc in (3.0, math.nan, math.inf, -3e9, "3e9", True):  # 3.0: GHz, not Hz
        with pytest.raises(ValueError, match="fc_hz"):
            city_channel.umi_lsp(fc)
    with pytest.raises(ValueError, match="excess_s"):
        city_channel.delay_spread_s(np.where(tau > 0, np.nan, tau), a)
    with pytest.raises(ValueError, match="excess_s"):
        city_channel.delay_spread_s(tau[:, :2], a)
    with pytest.raises(ValueError, match="gains"):
        city_channel.delay_spread_s(tau, np.zeros_like(a))
    with pytest.raises(ValueError, match="los"):
        city_channel.k_factor_db(a, np.array([1]))
    bs, toa, dt, ue = _trials(2, 4, 1)
    with pytest.raises(ValueError, match="excess_s"):
        city_errors.genie_fixes(bs, toa, dt[:, :3], ue[:, 2])
    with pytest.raises(ValueError, match="toa_s"):
        city_errors.receiver_fixes(bs, toa[:, :3], ue[:, 2])
    with pytest.raises(ValueError, match="threshold_db"):
        city_errors.genie_split(city, e, res, threshold_db=3.0)
    with pytest.raises(ValueError, match="not a run of"):
        city_errors.genie_split(city, e, SimpleNamespace(**{**res.__dict__, "bs_index": res.bs_index[:, ::-1]}))


def test_hearability_counts_the_heard_pairs_and_the_standards_probability():
    """The traced share of a bin is ``city_draw.heard_links``' share of its pairs; under the standard's model a pair
    whose median received power is the least heard is heard with probability 1/2, and the probability falls with
    distance; every pair is counted once."""
    from dpe5g.simulation import traced_draw

    city = city_paths.load_city(city_study.CITY)
    e = city_study.city_fig10(4, "otdoa", n_trials=1)
    dep = e.load_deployment()
    edges = np.array([0.0, 50.0, 100.0, 200.0, 1000.0])
    h = city_channel.hearability(city, e, dep, edges)
    assert h.n_pairs.sum() == city.n_ue * city.n_bs
    d = np.linalg.norm(city.ue_xyz[city.link_ue, :2] - city.bs_xyz[city.link_bs, :2], axis=-1)
    heard = traced_draw.heard_links(e, city, dep)
    sel = city.los & (d >= 50.0) & (d < 100.0)
    assert h.traced[0, 1] == pytest.approx(heard[sel].sum() / h.n_pairs[0, 1], abs=1e-12)
    assert np.all(np.diff(h.umi[1]) < 0)
    with pytest.raises(ValueError, match="edges_m"):
        city_channel.hearability(city, e, dep, [100.0, 50.0])
