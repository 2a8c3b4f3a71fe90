"""Drawing of the PRS frequency-reuse study (the urban scenario and Fig. 9 chapters; Fig. 10's case in the OTDoA
chapter) from its data, in the style of ``plots``: the links' SNR and SINR, and the RMSE and error CDFs with and
without reuse."""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.figure import Figure

from .plots import COLORS, style
from .result_plots import log_ticks


def plot_link_sinr(groups: dict):
    """The urban-scenario chapter: CDF of the per-link SNR (dashed) and SINR with PRS reuse (solid).

    Parameters
    ----------
    groups : dict
        {label: {``"snr_db"``: array, ``"sinr_db"``: array}}, per-sample dB, any shape (flattened); a colour per group.

    Returns
    -------
    matplotlib.figure.Figure
    """
    with style():
        fig = Figure(figsize=(7.4, 4.0), layout="constrained")
        ax = fig.subplots()
        lo, hi = np.inf, -np.inf
        for (label, g), col in zip(groups.items(), COLORS):
            for key, ls, what in (("snr_db", "--", "SNR"), ("sinr_db", "-", "SINR")):
                v = np.sort(np.ravel(g[key]))
                lo, hi = min(lo, np.quantile(v, 0.005)), max(hi, np.quantile(v, 0.995))
                ax.step(v, np.arange(1, v.size + 1) / v.size, ls, where="post", color=col, label=f"{label}: {what}")
        ax.axvline(0.0, color="k", lw=0.8, ls=":")
        ax.set_xlim(lo - 2, hi + 2)
        ax.set_ylim(0, 1)
        ax.set_yticks(np.arange(0, 1.01, 0.1))
        ax.set_xlabel("per-sample SNR / SINR of a link (dB)")
        ax.set_ylabel("CDF over links")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize=9, frameon=False)
    return fig


def plot_reuse_rmse(payload: dict):
    """The Fig. 9 chapter: RMSE against the nearest link's per-sample SNR for each M, a panel per set-up, log axis.

    Parameters
    ----------
    payload : dict
        ``"snrs_db"`` (S,), ``"m_values"`` (J,), ``"setups"`` {label: (S, J) RMSE, metres} (the same trials in each).

    Returns
    -------
    matplotlib.figure.Figure
    """
    snr = np.asarray(payload["snrs_db"])
    setups = payload["setups"]
    vals = np.concatenate([np.ravel(v) for v in setups.values()])
    with style():
        ncol = min(2, len(setups))
        nrow = -(-len(setups) // ncol)
        fig = Figure(figsize=(7.4, 3.4 * nrow + 0.6), layout="constrained")
        axes = np.atleast_1d(fig.subplots(nrow, ncol, sharey=True, squeeze=False).ravel())
        for ax in axes[len(setups):]:
            ax.set_visible(False)
        for ax, (label, rmse) in zip(axes, setups.items()):
            rmse = np.asarray(rmse)
            for j, (m, marker, col) in enumerate(zip(payload["m_values"], "osd^v<>", COLORS)):
                ax.plot(snr, rmse[:, j], "-", marker=marker, color=col, label=f"M = {m}")
            ax.set_title(textwrap.fill(label, 42), fontsize=9)
            ax.set_xticks(snr)
            ax.set_xlabel("SNR of the nearest link (dB)")
            log_ticks(ax, vals.min() / 1.15, vals.max() * 1.15)
        for ax in axes[::ncol]:
            ax.set_ylabel("RMSE (m)")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=len(payload["m_values"]),
                   fontsize=9, frameon=False)
    return fig


def plot_reuse_cdf(payload: dict):
    """The Fig. 10 chapter: error CDFs of the OTDoA-centred DPE (solid) and first-path OTDoA (dashed), reuse or not.

    Parameters
    ----------
    payload : dict
        ``"cases"``: {LoS case (a panel each): {label: {``"dpe"``: errors, ``"otdoa"``: errors}}}, errors in metres.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        When ``payload["cases"]`` is empty.
    """
    titles = {"two_of_four": "(a) 2 of 4 links LoS (paper's case)", "pr_los": "(b) LoS from eq. (11)"}
    n_cases = len(payload["cases"])
    if n_cases == 0:
        raise ValueError("plot_reuse_cdf: payload['cases'] is empty, need at least one LoS case")
    with style():
        fig = Figure(figsize=(7.4, 4.6 * n_cases), layout="constrained")
        axes = np.atleast_1d(fig.subplots(n_cases, 1))
        for ax, (case, runs) in zip(axes, payload["cases"].items()):
            for (label, errs), col in zip(runs.items(), COLORS):
                for key, ls, what in (("dpe", "-", "DPE on OTDoA fix"), ("otdoa", "--", "OTDoA, first path")):
                    v = np.sort(np.asarray(errs[key]))
                    ax.step(v, np.arange(1, v.size + 1) / v.size, ls, where="post", color=col,
                            label=f"{what}, {label}: 90 % {np.quantile(v, 0.9):.1f} m")
            ax.axhline(0.9, color="0.5", lw=0.7, ls=":")
            ax.set_xscale("log")
            ax.set_xlim(0.03, 1000)
            ax.set_ylim(0, 1)
            ax.set_yticks(np.arange(0, 1.01, 0.1))
            ax.set_xlabel("horizontal position error (m)")
            title = titles.get(case, case)
            ax.set_title(title if n_cases > 1 else title.removeprefix("(a) ").removeprefix("(b) "), fontsize=10)
            ax.set_ylabel("CDF")
            ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, -0.14), frameon=False)
    return fig
