"""The engine's receivers against the package's own: the grid search's shared first level, range offsets, the
readings' settings, the OTDoA-centred grid, PRS reuse and its co-channel sum, and the grid fixes on each SNR's
correlogram.  (The engine's runs, caches and keys: ``test_engine.py``.)"""

import numpy as np
import pytest

from dpe5g.phy import deployment, signal
from dpe5g.receivers import correlogram, cost, dpe, grid_search, receiver, search_config
from dpe5g.simulation import draw, engine, experiment, results, trial_draw, trials


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
    from dpe5g.studies import choices

    e = experiment.Experiment.build(name="o", n_trials=3, seed=2, snrs_db=(20.0,), m_values=(3, 5))
    res = engine.run(e, cache=tmp_path, progress=False)
    off = choices.range_offsets_m(res)
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
