"""The ToA fit with a clock prior (eq. (T1), ``toa_fit``) and the receiver settings of the clock-prior sweep
(``Receiver.clock_prior_s``, clock_window "free")."""

import math

import numpy as np
import pytest

from dpe5g.receivers import toa_fit
from dpe5g.simulation import experiment
from dpe5g.phy.nr import C


def _trials(n, m, seed, bias_sigma_m=1.5, noise_m=0.0):
    rng = np.random.default_rng(seed)
    bs = rng.uniform(-100.0, 100.0, (n, m, 3))
    bs[..., 2] = 10.0
    p = rng.uniform(-40.0, 40.0, (n, 2))
    z = 1.5
    bias = rng.normal(0.0, bias_sigma_m, n)
    d = np.linalg.norm(np.concatenate([p, np.full((n, 1), z)], axis=-1)[:, None] - bs, axis=-1)
    toa = (d + bias[:, None] + rng.normal(0.0, noise_m, (n, m))) / C
    return bs, toa, z, p, bias, rng


def _cost(bs, toa, z, xy, half):
    p = np.concatenate([xy, np.full(xy.shape[:-1] + (1,), z)], axis=-1)[..., None, :]
    r = C * toa - np.linalg.norm(p - bs, axis=-1)
    return np.sum((r - np.clip(r.mean(axis=-1), -half, half)[..., None]) ** 2, axis=-1)


@pytest.mark.parametrize("half", [np.inf, 4.5])
def test_noise_free_pseudoranges_give_the_position_and_the_clock(half):
    bs, toa, z, p, bias, rng = _trials(200, 4, 1)
    f = toa_fit.fit(bs, toa, z, p + rng.normal(0.0, 5.0, p.shape), half)
    assert np.max(np.linalg.norm(f.xy - p, axis=-1)) < 1e-6
    assert np.max(np.abs(f.bias_m - bias)) < 1e-6
    assert not f.on_edge.any() and not f.in_corner.any()


def test_the_fit_is_the_minimum_of_an_exhaustive_grid_over_its_windows():
    """On noisy trials, eq. (T1)'s cost at the fix is no higher than its least value on a 0.1 m grid of the window."""
    bs, toa, z, p, bias, rng = _trials(40, 5, 2, noise_m=3.0)
    start = p + rng.normal(0.0, 3.0, p.shape)
    for half_b in (np.inf, 2.0):
        f = toa_fit.fit(bs, toa, z, start, half_b, half_width_m=8.0)
        g = np.arange(-8.0, 8.0 + 1e-9, 0.1)
        for t in range(len(p)):
            grid = start[t] + np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
            c = _cost(bs[t], toa[t], z, grid, half_b)
            fixed = _cost(bs[t], toa[t], z, f.xy[t][None], half_b)[0]
            assert fixed <= c.min() + 1e-9, (t, half_b, fixed, c.min())
            assert np.linalg.norm(f.xy[t] - grid[np.argmin(c)]) < 0.2


def test_a_tight_clock_window_holds_the_bias_on_its_edge():
    bs, toa, z, p, bias, rng = _trials(50, 4, 3, bias_sigma_m=30.0)
    f = toa_fit.fit(bs, toa, z, p, bias_half_m=0.5)
    assert np.all(np.abs(f.bias_m) <= 0.5)
    assert np.all(f.on_edge[np.abs(bias) > 5.0])
    assert np.allclose(toa_fit.implied_bias_m(bs, toa, np.concatenate([f.xy, np.full((50, 1), z)], -1), 0.5),
                       f.bias_m)


def test_the_position_window_bounds_the_fix():
    bs, toa, z, p, bias, rng = _trials(50, 4, 4)
    start = p + 20.0  # the truth lies outside a 5 m window round the start
    f = toa_fit.fit(bs, toa, z, start, half_width_m=5.0)
    assert np.all(np.abs(f.xy - start) <= 5.0 + 1e-12) and f.in_corner.all()


def test_bad_input_names_the_parameter():
    bs, toa, z, p, _, _ = _trials(3, 4, 5)
    with pytest.raises(ValueError, match="at least 3 BSs"):
        toa_fit.fit(bs[:, :2], toa[:, :2], z, p)
    with pytest.raises(ValueError, match="bias_half_m must be > 0"):
        toa_fit.fit(bs, toa, z, p, bias_half_m=0.0)
    with pytest.raises(ValueError, match="half_width_m must be > 0"):
        toa_fit.fit(bs, toa, z, p, half_width_m=-1.0)
    with pytest.raises(ValueError, match=r"bs_xyz \(T, M, 3\)"):
        toa_fit.fit(bs, toa[:, :3], z, p)
    toa[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        toa_fit.fit(bs, toa, z, p)


def test_the_clock_prior_sets_the_dpe_window():
    e = experiment.Experiment.build(centring="otdoa", otdoa=True, m_values=(4,), snr_mode="link_budget", snrs_db=())
    base = e.receiver_search()
    assert base.bias_half_width_m == pytest.approx(3 * 5e-9 * C)
    wide = e.replace(clock_prior_s=100e-9).receiver_search()
    assert wide.bias_half_width_m == pytest.approx(3 * 100e-9 * C)
    assert wide.bias_boxes == math.ceil(2 * wide.bias_half_width_m / wide.box_m)
    free = e.replace(clock_window="free").receiver_search()
    assert free.bias_half_width_m == pytest.approx(math.sqrt(2) * free.half_width_m)
    # at its default the new setting leaves every stored key as it was
    assert e.replace(clock_prior_s=0.0).config_key() == e.config_key() != e.replace(clock_prior_s=30e-9).config_key()


def test_the_clock_settings_refuse_what_they_cannot_mean():
    with pytest.raises(ValueError, match="clock_prior_s must be"):
        experiment.Receiver(centring="otdoa", otdoa=True, clock_prior_s=2e-6)
    with pytest.raises(ValueError, match="centred on the truth"):
        experiment.Receiver(clock_prior_s=30e-9)
    with pytest.raises(ValueError, match="'free' is a window without a clock prior"):
        experiment.Receiver(centring="otdoa", otdoa=True, clock_window="free", clock_prior_s=30e-9)
