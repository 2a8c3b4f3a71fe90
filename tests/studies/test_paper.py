"""The paper's experiments (``dpe5g.studies.paper``), its readings and the claims' tests (``dpe5g.studies.readings``), and the list of
every experiment the store holds (``dpe5g.studies.catalog.store_experiments``)."""

import numpy as np
import pytest

from dpe5g.phy import channel, propagation, signal
from dpe5g.simulation import chunk_cache
from dpe5g.studies import catalog, nlos as nlos_study, paper, readings


def test_claim_intervals_give_each_claim_its_verdict_from_its_interval():
    """readings.claim_intervals / claim_verdicts: a claim whose interval lies inside the claim's range reproduces,
    outside it fails, across a bound it is unresolved; the ranges are read from the paper's constants."""
    snrs, ms = (10.0, 25.0, 40.0), (6, 12, 18, 24)
    rmse = np.array([[5.9, 5.0, 6.0, 6.5],   # 10 dB: within 6 m at M = 6, more BSs hurt
                     [2.0, 1.5, 1.0, 1.05],  # 25 dB: 5 % from 18 to 24
                     [0.9, 0.8, 0.7, 0.72]])  # 40 dB: below half of 10 dB, sub-metre
    fig9 = np.broadcast_to(rmse, (50, 3, 4))  # every trial's error its cell's RMSE: a point interval
    dpe_err = np.full(400, 1.5)  # p90 and p99 1.5 m
    otdoa_err = np.full(400, 40.0)
    iv = readings.claim_intervals(fig9, snrs, ms, dpe_err, otdoa_err, n_boot=100)
    assert list(iv) == list(readings.CLAIMS)
    assert iv["fig9_6m"].value == pytest.approx(5.9) and iv["fig9_submetre"].value == pytest.approx(0.7)
    assert iv["fig9_saturation"].value == pytest.approx(0.05)
    assert iv["fig10_gain"].value == pytest.approx(1 - 1.5 / 40)
    assert set(readings.claim_verdicts(iv).values()) == {"reproduces"}
    worse = readings.claim_verdicts(readings.claim_intervals(fig9 * 2, snrs, ms, dpe_err * 5, otdoa_err / 10,
                                                             n_boot=100))
    assert {k for k, v in worse.items() if v == "fails"} == set(readings.CLAIMS) - {
        "fig9_falls", "fig9_more_hurts", "fig9_saturation"}
    # a 90 % point whose interval holds the paper's 2 m: unresolved, counted neither way
    spread = np.random.default_rng(0).uniform(0, 2.0 / 0.9, 400)
    v = readings.claim_verdicts(readings.claim_intervals(fig9, snrs, ms, spread, otdoa_err, n_boot=200))
    assert v["fig10_dpe_p90"] == "unresolved"
    assert readings.verdict_counts(v.values())["unresolved"] >= 1
    assert readings.CLAIMS["fig10_dpe_p90"][2] == (0.0, paper.PAPER_FIG10_DPE_M[0.9])
    assert readings.CLAIMS["fig10_otdoa_p90"][2] == pytest.approx(
        ((1 - readings.OTDOA_P90_TOLERANCE) * paper.PAPER_FIG10_OTDOA_M[0.9],
         (1 + readings.OTDOA_P90_TOLERANCE) * paper.PAPER_FIG10_OTDOA_M[0.9]))
    with pytest.raises(ValueError, match="missing SNRs"):
        readings.claim_intervals(fig9[:, :2], snrs[:2], ms, dpe_err, otdoa_err)
    with pytest.raises(ValueError, match="fig9_err_m must be"):
        readings.claim_intervals(fig9[:, :, :3], snrs, ms, dpe_err, otdoa_err)


def test_readings_are_experiments_that_differ_in_their_reading_only():
    base = readings.experiments("as_read")
    assert base["fig9"] == paper.fig9_truth() and base["otdoa_detector"] == "first_path"
    assert readings.experiments("peak_otdoa")["otdoa_detector"] == "peak"
    both = readings.experiments("span_total")
    for k in ("fig9", "fig10_dpe"):
        assert both[k].scenario.delay_spread_def == "span" and both[k].links.snr_convention == "total"
        assert both[k].receiver.centring == "truth" and both[k].run.seed == base[k].run.seed
    assert both["fig10_dpe"].receiver.otdoa and both["fig10_dpe"].scenario.los_mode == "two_of_four"
    assert both["fig9"].links.snrs_db == paper.READING_SNRS_DB and both["fig9"].run.n_trials == paper.READING_TRIALS
    honest = readings.experiments("honest")["fig9"]
    assert honest == readings.fig9_honest_readings() and honest.run.n_trials == paper.READING_TRIALS
    assert honest.replace(name="fig09-honest", snrs_db=paper.fig9_honest().links.snrs_db,
                          n_trials=paper.FIG9_HONEST_TRIALS) == paper.fig9_honest()
    assert readings.experiments("span", n_trials=7)["fig10_dpe"].run.n_trials == 7
    # the reuse reading: the honest receivers of Fig. 9 (per-link power) and Fig. 10 with Table I's reuse, on the
    # figures' seeds, differing from their reuse-free experiments in the reuse only
    reuse = readings.experiments("reuse")
    assert reuse["fig9"].scenario.prs_reuse == reuse["fig10_dpe"].scenario.prs_reuse == paper.REUSE and reuse["fig9"].scenario.co_channel
    assert reuse["fig9"].replace(name="fig09-power", prs_reuse=0) == paper.fig9_power()
    assert reuse["fig9"].links.snr_mode == "nearest" and reuse["fig9"].run.n_trials >= paper.READING_TRIALS
    f10 = paper.fig10(reuse["fig10_dpe"].run.n_trials)[("two_of_four", "otdoa")]
    assert reuse["fig10_dpe"].replace(name=f10.run.name, prs_reuse=0) == f10
    assert reuse["fig10_dpe"] is reuse["fig10_otdoa"] and reuse["fig10_dpe"].run.n_trials >= paper.READING_TRIALS
    with pytest.raises(ValueError, match="reading must be one of"):
        readings.experiments("literal")
    with pytest.raises(ValueError, match="not both"):
        readings.honest_runs({"prs_reuse": paper.REUSE, "nlos_excess_median_s": 30e-9}, 2)
    with pytest.raises(ValueError, match="changes nothing else"):
        readings.truth_centred_runs({"los_mode": "nearest_two_los", "snr_convention": "total"}, 2)
    assert set(channel.DELAY_SPREAD_DEFS) == {"rms", "span"}
    assert signal.per_sample_snr_db(40.0, "total") == pytest.approx(40 - 10 * np.log10(4096))
    with pytest.raises(ValueError, match="convention"):
        signal.per_sample_snr_db(40.0, "after_correlation")


def test_the_nlos_chapters_readings_change_what_they_name():
    as_read, f10 = readings.experiments("as_read"), paper.fig10()
    # the certified search in the paper's window: only the optimiser differs from the truth-centred grid
    cert = readings.experiments("certified_window")
    search = nlos_study.certified_in_paper_window()
    grid = as_read["fig10_dpe"].receiver.search
    assert search.method == "bnb" != grid.method
    assert (search.half_width_m, search.bias_half_width_m) == (grid.half_width_m, grid.bias_half_width_m)
    assert cert["fig9"].receiver.centring == cert["fig10_dpe"].receiver.centring == "truth"
    assert cert["fig9"].replace(name="fig09", search=grid, snrs_db=paper.fig9_truth().links.snrs_db) == paper.fig9_truth()
    assert cert["fig10_dpe"].replace(name=f10[("two_of_four", "truth")].run.name, search=grid) == \
        f10[("two_of_four", "truth")]
    assert cert["fig10_otdoa"] == f10[("two_of_four", "otdoa")]
    # the deterministic LoS case: Fig. 10's LoS only; Fig. 9 as read
    near = readings.experiments("nearest_los")
    assert near["fig9"] == as_read["fig9"] and near["fig10_dpe"].scenario.los_mode == "nearest_two_los"
    for k, cen in (("fig10_dpe", "truth"), ("fig10_otdoa", "otdoa")):
        e = f10[("two_of_four", cen)]
        assert near[k].replace(name=e.run.name, los_mode="two_of_four") == e
    # the honest receiver with TR 38.901's UMi excess delay: the honest reading's experiments with it on
    honest = readings.experiments("honest")
    for m in (nlos_study.UMI.median_s,):
        ex = readings.experiments("umi")
        assert ex["fig9"].scenario.nlos_excess_median_s == ex["fig10_dpe"].scenario.nlos_excess_median_s == m
        assert ex["fig9"].scenario.nlos_excess_sigma_lg == ex["fig10_dpe"].scenario.nlos_excess_sigma_lg \
            == nlos_study.NLOS_EXCESS_SIGMA_LG
        assert ex["fig9"].replace(name=honest["fig9"].run.name, nlos_excess_median_s=0.0,
                                  nlos_excess_sigma_lg=0.0) == honest["fig9"]
        e10 = honest["fig10_dpe"].replace(n_trials=ex["fig10_dpe"].run.n_trials)
        assert ex["fig10_dpe"].replace(name=e10.run.name, nlos_excess_median_s=0.0, nlos_excess_sigma_lg=0.0) == e10
        assert ex["fig10_dpe"] is ex["fig10_otdoa"] and ex["otdoa_detector"] == "first_path"
    # the blind Fig. 9 beside the honest reading's: the same trials, the window on the OTDoA fix instead of the prior
    blind = nlos_study.fig9_blind_readings()
    assert blind.receiver.centring == "otdoa" and blind.receiver.otdoa
    assert blind.replace(name=honest["fig9"].run.name, centring="prior", otdoa=False) == honest["fig9"]


def test_store_experiments_one_entry_per_run_at_its_largest_count():
    exps = catalog.store_experiments()
    dirs = [chunk_cache.cache_dir(e).name for e in exps]
    assert len(dirs) == len(set(dirs))
    by_dir = dict(zip(dirs, exps))
    # Chapter 5 reads the first REUSE_COMPARE_TRIALS of the reuse reading's run: listed once, at the reading's count
    assert by_dir[chunk_cache.cache_dir(paper.fig9_power(reuse=paper.REUSE)).name].run.n_trials == paper.READING_TRIALS
    for e in (paper.fig9_honest(), paper.fig9_truth(), paper.fig10()[("pr_los", "truth")], readings.fig9_honest_readings(),
              paper.fig9_all_los(*paper.ALL_LOS_CASES[-1])):
        assert by_dir[chunk_cache.cache_dir(e).name].run.n_trials >= e.run.n_trials
    # the NLoS chapter's runs and the readings built on them are all listed
    for e in (*nlos_study.all_experiments(), nlos_study.fig9_blind_readings(),
              *(readings.experiments(n)["fig9"] for n in readings.READINGS)):
        assert chunk_cache.cache_dir(e).name in by_dir, e.run.name
