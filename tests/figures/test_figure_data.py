"""The figures' data: the cost surfaces of Figs. 6 and 8 by the FFT form of eq. (10)."""

import jax
import numpy as np

from dpe5g.phy import nr, signal
from dpe5g.receivers import cost
from dpe5g.figures import data as figure_data
from dpe5g.phy.nr import PAPER


def test_cost_on_grid_is_eq10_at_every_sampled_grid_point():
    """``cost_on_grid`` against eq. (10) evaluated at each point (``cost.ml_cost``) on 300 points of a Fig. 6-like
    grid (8 BSs on a 150 m ring, the 3-tap channel, 10 dB, the clock bias off its grid): within 2e-5 of the peak."""
    rng = np.random.default_rng(6)
    m = 8
    ang = np.arange(m) * 2 * np.pi / m + 0.2
    bs = np.stack([150 * np.cos(ang), 150 * np.sin(ang), np.full(m, 10.0)], axis=-1)
    ue, bias = np.array([1.3, -0.7, 2.0]), 3.1e-9
    prs = nr.prs_matrix(range(1, m + 1))
    ts = PAPER.sample_period_s
    y = signal.received_samples(jax.random.PRNGKey(6), prs, np.tile(figure_data.FIG6_TAPS, (m, 1)),
                                np.tile(np.arange(3) * ts, (m, 1)), cost.toa(ue, bs, 0.0), 10.0, bias)
    axis = np.arange(-10.0, 10.0 + 1e-9, 0.25)
    surface = figure_data.cost_on_grid(y, prs, bs, ue[0] + axis, ue[1] + axis, ue[2], bias, 12)
    assert surface.shape == (axis.size, axis.size)
    iy, ix = rng.integers(0, axis.size, size=(2, 300))
    iy[0], ix[0] = np.unravel_index(np.argmax(surface), surface.shape)  # the peak among them
    xyz = np.stack([ue[0] + axis[ix], ue[1] + axis[iy], np.full(ix.size, ue[2])], axis=-1)
    exact = np.asarray(cost.ml_cost(y, prs, cost.toa(xyz, bs, bias), 12, PAPER.scs_hz))
    err = np.abs(surface[iy, ix] - exact)
    assert err.max() <= 2e-5 * exact.max()
    assert err.max() > 0  # an interpolation between the correlogram's grid points, not eq. (10) itself
