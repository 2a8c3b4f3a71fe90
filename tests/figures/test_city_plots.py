"""The city's map of where each receiver wins (``city_plots.plot_error_map``): every trial UE drawn at its place with
its own value, the colour scale symmetric about 0 and its ends marked, text legible."""

import numpy as np

from dpe5g.figures import city_plots, plots


def test_the_error_map_draws_each_ue_with_its_values():
    rng = np.random.default_rng(0)
    ue = rng.uniform(0, 100, (50, 2))
    diff = rng.normal(0, 20, 50)
    n_los = rng.integers(0, 5, 50)
    roof = np.array([[[10, 10, 20], [30, 10, 20], [10, 30, 20]], [[0, 0, 0], [5, 0, 0], [0, 5, 0]]], float)
    fig = city_plots.plot_error_map(roof, [[50, 50], [80, 20], [20, 80]], (0, 0, 100, 100), ue, diff, n_los, 4, 15.0)
    plots.check_legible(fig)
    top, bottom = (ax for ax in fig.axes if ax.get_label() != "<colorbar>")
    for ax, values in ((top, diff), (bottom, n_los)):
        (dots,) = ax.collections[1:]
        assert np.array_equal(dots.get_offsets(), ue) and np.array_equal(dots.get_array(), values)
        assert len(ax.collections[0].get_paths()) == 1  # the roof drawn, the ground triangle not
    assert top.collections[1].norm.vmin == -15.0 and top.collections[1].norm.vmax == 15.0
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 2 and "DPE better" in bars[0].get_ylabel()
