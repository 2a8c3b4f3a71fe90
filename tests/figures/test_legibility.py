"""Figure legibility (``plots.check_legible``): every text at least 9 pt and every figure narrow enough that the
book shows it unshrunk, for the paper's figures (drawn from their committed data) and the chapters' own plots (drawn
from small made-up payloads: the rule is about layout, not values).  The browser test checks the other half: the
book shows every image at its own size."""

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from dpe5g.studies import choices
from dpe5g.figures import plots, registry as figures, result_plots

DATA = Path(__file__).resolve().parents[2] / "figures" / "data"


def test_small_text_and_wide_figures_are_refused():
    with plots.style():
        fig = Figure(figsize=(6.0, 3.0))
        ax = fig.subplots()
        ax.set_title("fine")
        ax.text(0.5, 0.5, "too small", fontsize=8)
        with pytest.raises(ValueError, match=r"'too small' is 8 pt; every text must be at least 9 pt"):
            plots.check_legible(fig)
        wide = Figure(figsize=(9.0, 3.0))
        wide.subplots().plot([0, 1])
        with pytest.raises(ValueError, match=r"9.\d\d in wide; at most 7.68 in"):
            plots.check_legible(wide)
        with pytest.raises(ValueError, match="at least 9 pt"):
            figures.glue("small", fig)


@pytest.mark.parametrize("fig_id", sorted(figures.REGISTRY))
def test_the_papers_figures_are_legible(fig_id):
    plots.check_legible(figures.render(json.loads((DATA / f"{fig_id}.json").read_text())))


def _chapter_plots() -> dict:
    """{name: a function drawing the plot}: drawn inside the test, not while pytest collects (collection runs in
    every xdist worker at once, and computing there would race on JAX's compile cache)."""
    rng = np.random.default_rng(0)
    snr, ms = np.array([0.0, 10.0, 20.0, 30.0, 40.0]), [4, 6, 12, 18, 24]
    rmse = lambda: rng.uniform(0.5, 9.0, (snr.size, len(ms)))
    errs = lambda: rng.lognormal(0.0, 1.5, 500)
    long_label = "per-link power from the path loss, with co-channel interference"
    return {
        "window study": lambda: result_plots.plot_window_study(
            [dict(setup=s, m=m, n_taps=n, rmse_m=rng.uniform(1, 5), p90_m=rng.uniform(1, 9))
             for s in ("paper's SNR", long_label) for m in (4, 6, 12) for n in (1, 2, 4, 8, 12, 16)]),
        "link SINR": lambda: result_plots.plot_link_sinr(
            {f"{k}{'st' if k == 1 else 'th'} nearest links": {"snr_db": rng.normal(-5 * k, 5, 300),
                                                              "sinr_db": rng.normal(-6 * k, 5, 300)} for k in (1, 2, 5)}),
        "reuse RMSE": lambda: result_plots.plot_reuse_rmse(
            {"snrs_db": snr, "m_values": ms, "setups": {f"({c}) {long_label}": rmse() for c in "abc"}}),
        "reuse CDF": lambda: result_plots.plot_reuse_cdf(
            {"cases": {c: {"no reuse": {"dpe": errs(), "otdoa": errs()}, "reuse 6": {"dpe": errs(), "otdoa": errs()}}
                       for c in ("two_of_four", "pr_los")}}),
        "RMSE and bound": lambda: result_plots.plot_rmse_and_bound(
            {"snrs_db": snr, "m_values": ms, "curves": {"a receiver": rmse(), "another": rmse()},
             "bound_m": rmse() / 9}),
        "p90 sweep": lambda: result_plots.plot_p90_sweep(
            {"x": [0, 10, 30, 100], "xlabel": "median excess delay of an NLoS link (ns)",
             "panels": {f"({c}) {long_label}": {f"receiver {k}, {long_label}": {"p90_m": [3, 4, 6, 12],
                                                                                 "lo_m": [2, 3, 5, 11],
                                                                                 "hi_m": [4, 5, 7, 13]}
                                                 for k in range(5)} for c in "ab"},
             "marks": {"the paper's OTDoA: 90 % at 42 m": 42.0}}),
        "plateau": lambda: plots.plot_plateau(choices.plateau_payload()),
    }


@pytest.mark.parametrize("name", list(_chapter_plots()))
def test_the_chapters_plots_are_legible(name):
    plots.check_legible(_chapter_plots()[name]())
