"""Figure legibility (``plots.check_legible``): every text at least 9 pt and every figure narrow enough that the
book shows it unshrunk, for the paper's figures (drawn from their committed data) and the chapters' own plots (drawn
from small made-up payloads: the rule is about layout, not values).  The browser test checks the other half: the
book shows every image at its own size."""

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from dpe5g import figures, plots, result_plots, studies

DATA = Path(__file__).resolve().parents[1] / "figures" / "data"


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


def _chapter_plots():
    rng = np.random.default_rng(0)
    snr, ms = np.array([0.0, 10.0, 20.0, 30.0, 40.0]), [4, 6, 12, 18, 24]
    rmse = lambda: rng.uniform(0.5, 9.0, (snr.size, len(ms)))
    errs = lambda: rng.lognormal(0.0, 1.5, 500)
    long_label = "per-link power from the path loss, with co-channel interference"
    yield "window study", result_plots.plot_window_study(
        [dict(setup=s, m=m, n_taps=n, rmse_m=rng.uniform(1, 5), p90_m=rng.uniform(1, 9))
         for s in ("paper's SNR", long_label) for m in (4, 6, 12) for n in (1, 2, 4, 8, 12, 16)])
    yield "link SINR", result_plots.plot_link_sinr(
        {f"{k}{'st' if k == 1 else 'th'} nearest links": {"snr_db": rng.normal(-5 * k, 5, 300),
                                                          "sinr_db": rng.normal(-6 * k, 5, 300)} for k in (1, 2, 5)})
    yield "reuse RMSE", result_plots.plot_reuse_rmse(
        {"snrs_db": snr, "m_values": ms, "setups": {f"({c}) {long_label}": rmse() for c in "abc"}})
    yield "reuse CDF", result_plots.plot_reuse_cdf(
        {"cases": {c: {"no reuse": {"dpe": errs(), "otdoa": errs()}, "reuse 6": {"dpe": errs(), "otdoa": errs()}}
                   for c in ("two_of_four", "pr_los")}})
    yield "RMSE and bound", result_plots.plot_rmse_and_bound(
        {"snrs_db": snr, "m_values": ms, "curves": {"a receiver": rmse(), "another": rmse()}, "bound_m": rmse() / 9})
    yield "plateau", plots.plot_plateau(studies.plateau_payload())


@pytest.mark.parametrize("name, fig", list(_chapter_plots()), ids=lambda v: v if isinstance(v, str) else "")
def test_the_chapters_plots_are_legible(name, fig):
    plots.check_legible(fig)
