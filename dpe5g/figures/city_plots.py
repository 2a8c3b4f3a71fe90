"""Drawing of the ray-traced city's results (``city_study``) in the style of ``plots``: the receivers' error CDFs,
the NLoS first-path excess delay against TR 38.901's log-normal, the LoS share against eq. (11), and the map of where
each receiver wins."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from scipy import stats

from ..phy import propagation
from .plots import style

#: each receiver's label, colour, line style and width on the city's CDF (as Fig. 10's, ``result_plots.plot_cdf``)
RECEIVERS = {"dpe_otdoa": ("DPE centred on the OTDoA fix", "#1f77b4", "-", 2.4),
             "dpe_truth": ("DPE centred on the truth (the paper's set-up)", "0.45", "-.", 1.3),
             "otdoa_first_path": ("OTDoA, first-path ToA", "#d62728", "-", 1.3),
             "otdoa_peak": ("OTDoA, peak ToA (naive)", "#ff7f0e", ":", 1.6)}


def plot_city_cdf(errors: dict, grid_m):
    """The error CDF of each receiver on the city's trials.

    Parameters
    ----------
    errors : dict
        {receiver of ``RECEIVERS``: horizontal errors (T,) m}, on the same trials.
    grid_m : float (G,)
        The error grid, metres (log-spaced).

    Returns
    -------
    matplotlib.figure.Figure
    """
    grid = np.asarray(grid_m)
    with style():
        fig = Figure(figsize=(7.4, 5.6), layout="constrained")
        ax = fig.subplots()
        for key, (lab, col, ls, lw) in RECEIVERS.items():
            e = np.sort(np.asarray(errors[key]))
            cdf = np.searchsorted(e, grid, side="right") / e.size
            ax.step(grid, cdf, ls, where="post", color=col, lw=lw,
                    label=f"{lab}: 50 % {np.quantile(e, 0.5):.1f} m, 90 % {np.quantile(e, 0.9):.1f} m")
        for lev in (0.5, 0.9):
            ax.axhline(lev, color="0.5", lw=0.7, ls=":")
        ax.set_xscale("log")
        ax.set_xlim(grid[0], grid[-1])
        ax.set_ylim(0, 1.0)
        ax.set_yticks(np.arange(0, 1.01, 0.1))
        ax.set_xlabel("horizontal position error (m)")
        ax.set_ylabel("CDF")
        ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, -0.14), frameon=False)
    return fig


def plot_excess(populations: dict) -> Figure:
    """Histograms of lg Δτ of NLoS links' first paths, a population each, with TR 38.901's UMi normal over them.

    Parameters
    ----------
    populations : dict
        {label: the first-path excess delays of a population's NLoS links, seconds (n,)} (``city_study.link_populations``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    umi = propagation.TR38901_EXCESS_DELAY[propagation.NLOS_EXCESS_ROW]
    edges = np.arange(-11.0, -5.49, 0.125)
    x = np.linspace(edges[0], edges[-1], 400)
    colours = ("#3182bd", "#31a354", "#e6550d", "#756bb1")
    with style():
        fig = Figure(figsize=(7.4, 4.4), layout="constrained")
        ax = fig.subplots()
        for (label, dt), colour in zip(populations.items(), colours):
            lg = np.log10(np.maximum(np.asarray(dt, dtype=float), 1e-12))
            ax.hist(np.clip(lg, edges[0], edges[-1]), bins=edges, density=True, histtype="step", lw=1.8, color=colour,
                    label=f"{label} ({lg.size}): mean {lg.mean():.2f}, σ {lg.std():.2f}")
        ax.plot(x, stats.norm(umi.mu_lg, umi.sigma_lg).pdf(x), color="#d62728", lw=2, ls="--",
                label=f"TR 38.901 Table 7.6.9-1, UMi: mean {umi.mu_lg:g}, σ {umi.sigma_lg:g}")
        ax.set_xlabel("lg(first-path excess delay Δτ / 1 s)   (−9: 1 ns, −8: 10 ns, −7: 100 ns)")
        ax.set_ylabel("density (per decade)")
        ax.legend(fontsize=9, loc="upper left", frameon=False)
    return fig


def plot_los_share(by_distance: dict) -> Figure:
    """The traced LoS share of (UE, BS) pairs by 2-D distance beside eq. (11)'s probability.

    Parameters
    ----------
    by_distance : dict
        ``city_study.los_by_distance``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    c = np.asarray(by_distance["centre_m"])
    with style():
        fig = Figure(figsize=(7.4, 4.0), layout="constrained")
        ax = fig.subplots()
        ax.plot(c, by_distance["share"], "o-", color="#1f77b4", label="traced city: share of pairs with a clear line")
        ax.plot(c, by_distance["eq11"], "s--", color="#d62728", label="eq. (11), TR 38.901 UMi")
        ax.set_xlabel("2-D distance between UE and BS (m)")
        ax.set_ylabel("LoS probability")
        ax.set_ylim(0, 1)
        ax.legend(fontsize=9, loc="upper right", frameon=False)
    return fig


def plot_error_map(triangles, bs_xy, region, ue_xy, diff_m, n_los, m: int, limit_m: float) -> Figure:
    """Plan views of the city: the buildings, the BSs and each trial UE coloured by its paired error difference
    (DPE − OTDoA, diverging about 0), and beside it by the number of its m links that are LoS.

    Parameters
    ----------
    triangles : float (K, 3, 3)
        The buildings' triangles (``city_paths.load_view``), metres; those above the ground drawn from above.
    bs_xy : float (B, 2)
        The BSs, metres.
    region : float (4,)
        (x_min, y_min, x_max, y_max), metres: the panels' extent.
    ue_xy : float (T, 2)
        The trials' UEs, metres.
    diff_m : float (T,)
        DPE's error less OTDoA's on each trial, metres (negative: DPE the better).
    n_los : int (T,)
        LoS links among each trial's m.
    m : int
        The links per trial.
    limit_m : float
        The colour scale's end, metres: differences beyond ±limit_m take the end colours (the colour bar's arrows).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.collections import PolyCollection
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm, Normalize

    tri = np.asarray(triangles, float)
    roofs = tri[(tri[..., 2] > 0.5).all(axis=1)][..., :2]
    x0, y0, x1, y1 = (float(v) for v in region)
    with style():
        fig = Figure(figsize=(6.2, 10.6), layout="constrained")
        axes = fig.subplots(2, 1)
        los_cmap = colormaps["viridis"].resampled(m + 1)  # (sequential: not the upper panel's two sides)
        for ax, values, cmap, norm in (
                (axes[0], np.asarray(diff_m), "RdBu_r", Normalize(-limit_m, limit_m)),
                (axes[1], np.asarray(n_los), los_cmap, BoundaryNorm(np.arange(-0.5, m + 1), m + 1))):
            ax.add_collection(PolyCollection(roofs, facecolors="0.82", edgecolors="0.82", linewidths=0.2))
            dots = ax.scatter(*np.asarray(ue_xy).T, c=values, cmap=cmap, norm=norm, s=9, linewidths=0)
            ax.plot(*np.asarray(bs_xy).T, "k^", ms=6, label="BS")
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
            ax.set_aspect("equal")
            ax.set_xlabel("x, east (m)")
            ax.set_ylabel("y, north (m)")
            if ax is axes[0]:
                bar = fig.colorbar(dots, ax=ax, extend="both", shrink=0.9)
                bar.set_label("DPE − OTDoA error (m)\n< 0: DPE better")
            else:
                bar = fig.colorbar(dots, ax=ax, ticks=range(m + 1), shrink=0.9)
                bar.set_label(f"LoS links of the {m}")
        axes[0].legend(loc="upper left", bbox_to_anchor=(0.0, 1.0), fontsize=9, framealpha=0.9)
    return fig
