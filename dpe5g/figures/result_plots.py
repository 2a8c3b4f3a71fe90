"""Drawing of the Monte Carlo results from their data (never from live computation), in the style of ``plots``.

Figs. 9 and 10, the readings of the paper against its claims, the studies of the Fig. 9 and bounds chapters, and the
PRS frequency-reuse study (the urban scenario and Fig. 9 chapters; Fig. 10's case in the OTDoA chapter): the links' SNR
and SINR, and the RMSE and error CDFs with and without reuse."""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator, FormatStrFormatter, LogLocator, MultipleLocator, NullFormatter

from ..studies.paper import PAPER_FIG9_RMSE_M, PAPER_FIG9_SUB_METRE_M, PAPER_FIG10_DPE_M, PAPER_FIG10_OTDOA_M
from .plots import COLORS, style


#: the paper's stated values (``dpe5g.studies.paper``'s PAPER_*) are drawn on Figs. 9 and 10 as black-edged stars
#: (``PAPER_MARKER``; no curve of ours uses a star) labelled "paper (text)"
PAPER_MARKER = dict(marker="*", color="k", markersize=13, markerfacecolor="#ffd500", markeredgecolor="k", mew=1.0,
                    ls="none", zorder=6, clip_on=False)


def log_ticks(ax, lo: float, hi: float) -> None:
    """A log y axis over [lo, hi] with enough labelled ticks to read values off.

    Within about a decade and a half: labels at 1, 1.2, 1.5, 2, 3, 4, 5, 6, 8 × 10^k and a light minor grid in
    between (steps of 0.1 × 10^k up to 2 × 10^k), so a value reads to 0.1 m around 1 m.  Up to three decades: labels
    at 1, 2, 5 × 10^k, minor grid at the other integers.  Wider: labels at the decades.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        The axes whose y axis is set.
    lo, hi : float
        The axis' limits, 0 < lo < hi.
    """
    ax.set_yscale("log")
    ax.set_ylim(lo, hi)
    span = np.log10(hi / lo)
    if span <= 1.5:
        major = (1.0, 1.2, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)
        minor = (1.1, 1.3, 1.4, 1.6, 1.7, 1.8, 1.9, 2.5, 3.5, 4.5, 7.0, 9.0)
    elif span <= 3.0:
        major, minor = (1.0, 2.0, 5.0), (3.0, 4.0, 6.0, 7.0, 8.0, 9.0)
    else:
        major, minor = (1.0,), (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)
    decades = 10.0 ** np.arange(np.floor(np.log10(lo)) - 1, np.ceil(np.log10(hi)) + 1)

    def at(mantissas):
        v = np.round(np.outer(decades, mantissas).ravel(), 12)
        return v[(v >= lo) & (v <= hi)]

    ax.yaxis.set_major_locator(FixedLocator(at(major)))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_locator(FixedLocator(at(minor)))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="major", alpha=0.45)
    ax.grid(True, which="minor", alpha=0.15)


def _paper_fig9_text(ax_top, ax, pv: dict) -> None:
    """Fig. 9's values stated in the paper's text: its 6 m on the short top panel ``ax_top`` of a broken axis, its
    sub-metre line on ``ax`` below, and the break marks between them."""
    ax_top.plot([pv["snr_db"]], [pv["rmse_m"]], **PAPER_MARKER,
                label=f"paper (text): within {pv['rmse_m']:g} m, M = {pv['m']} at {pv['snr_db']:g} dB")
    ax_top.set_ylim(pv["rmse_m"] - 1.0, pv["rmse_m"] + 1.0)
    ax_top.yaxis.set_major_locator(MultipleLocator(1.0))
    ax_top.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax_top.grid(True, which="major", alpha=0.35)
    ax_top.spines["bottom"].set_visible(False)
    ax.spines["top"].set_visible(False)
    ax_top.tick_params(bottom=False, labelbottom=False)
    for a, y in ((ax_top, 0.0), (ax, 1.0)):  # the break marks
        a.plot([0.0, 1.0], [y, y], transform=a.transAxes, ls="none", marker=[(-1, -0.5), (1, 0.5)],
               markersize=10, color="k", mew=1, clip_on=False)
    ax.axhline(PAPER_FIG9_SUB_METRE_M, color="k", lw=1.0, ls=(0, (1, 2)), zorder=1.5,
               label="paper (text): sub-metre with more BSs at high SNR (no SNR given)")


def plot_rmse_vs_snr(payload: dict):
    """Fig. 9: RMSE of the horizontal error against the per-sample SNR, one colour per M.

    Solid: the honest receiver (window on a prior, certified search), dashed: the paper's truth-centred grid.  A
    payload with one receiver only (the chapters' studies) is drawn solid.  Where the SNR axis holds 10 dB and M = 6
    is drawn, the values the paper's text states are drawn as well (``PAPER_FIG9_*``).

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.rmse_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = payload["data"]
    c = payload["config"]
    snr = np.asarray(c["snrs_db"])
    recv = [r for r in ("honest", "truth") if r in d]
    style_of = {"honest": ("-", "honest: prior-centred, certified"), "truth": ("--", "paper's set-up: truth-centred")}
    pv = PAPER_FIG9_RMSE_M
    paper_text = snr.min() <= pv["snr_db"] <= snr.max() and pv["m"] in c["m_values"]
    with_bound = "bound_m" in d and "honest" in d
    with style():
        fig = Figure(figsize=(7.4, (6.0 if paper_text else 5.2) + (4.4 if with_bound else 0.0)), layout="constrained")
        if with_bound:  # panel (b) below: the honest RMSE beside the Cramér–Rao bound on a log axis
            top, bottom = fig.subfigures(2, 1, height_ratios=[6.0 if paper_text else 5.2, 4.4])
        else:
            top, bottom = fig, None
        if paper_text:  # a broken axis: the paper's 6 m on a short top panel, our curves readable to 0.1 m below
            ax_top, ax = top.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [1, 5], "hspace": 0.02})
        else:
            ax_top, ax = None, top.subplots()
        for r in recv:
            ls, lab = style_of[r] if len(recv) > 1 else ("-", "")
            rmse = np.asarray(d[r]["rmse_m"])
            for j, (m, marker, col) in enumerate(zip(c["m_values"], "osd^v<>", COLORS)):
                ax.plot(snr, rmse[:, j], ls, marker=marker, color=col, mfc="none" if ls == "--" else col,
                        label=f"M = {m}" if r == recv[0] else None)
        for r in recv if len(recv) > 1 else ():
            ax.plot([], [], style_of[r][0], color="0.3",
                    label=f"{style_of[r][1]} ({c['receivers'][r]['n_trials']} trials)")
        vals = np.concatenate([np.asarray(d[r]["rmse_m"]).ravel() for r in recv])
        if paper_text:
            _paper_fig9_text(ax_top, ax, pv)
            vals = np.concatenate([vals, [PAPER_FIG9_SUB_METRE_M]])
        lo, hi = vals.min(), vals.max()
        if hi / lo < 4:  # a narrow range: linear axis, labelled every 0.1 m
            ax.set_ylim(lo - 0.05 * (hi - lo) - 0.02, hi + 0.05 * (hi - lo) + 0.02)
            ax.yaxis.set_major_locator(MultipleLocator(0.1))
            ax.yaxis.set_major_formatter(FormatStrFormatter("%.1f"))
            ax.grid(True, which="major", alpha=0.35)
        else:  # a wide range: log axis with labelled intermediate ticks
            log_ticks(ax, lo / 1.15, hi * 1.15)
        ax.set_xlabel("SNR per time-domain sample, before correlation (dB)")
        ax.set_ylabel("RMSE (m)")
        ax.set_xticks(snr)
        handles, labels = ax.get_legend_handles_labels()
        if ax_top is not None:
            h2, l2 = ax_top.get_legend_handles_labels()
            handles, labels = handles + h2, labels + l2
        ax.legend(handles, labels, fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2,
                  frameon=False)
        (ax_top or ax).set_title(("(a) " if with_bound else "") + f"{100 * d['los_share_all']:.0f} % of links LoS",
                                 fontsize=10)
        if with_bound:
            axb = bottom.subplots()
            _draw_rmse_and_bound(axb, snr, c["m_values"], {"": d["honest"]["rmse_m"]}, d["bound_m"])
            axb.set_title(f"(b) honest receiver (solid), Cramér–Rao bound (dotted, {c['bound_trials']} trials);\n"
                          "the bound assumes every link's tap delays known", fontsize=10)
            axb.set_xlabel("SNR per time-domain sample, before correlation (dB)")
            axb.set_ylabel("RMSE (m)")
            axb.set_xticks(snr)
    return fig


def plot_cdf(payload: dict):
    """Fig. 10: error CDFs of DPE and OTDoA: (a) the paper's case (2 of 4 links LoS), (b) LoS from eq. (11).

    Both panels carry the points the paper's text states (``PAPER_FIG10_*``) as stars.

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.cdf_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    grid = np.asarray(payload["config"]["error_grid_m"])
    data = payload["data"]
    titles = {"two_of_four": "(a) 2 of 4 links LoS (paper's case)", "pr_los": "(b) LoS from eq. (11)"}
    # the two honest DPE curves nearly coincide: the OTDoA-centred one wide and solid, the prior-centred one thin and
    # dashed on top of it, so both stay visible
    curves = [("dpe_otdoa", "DPE centred on OTDoA fix", "#1f77b4", "-", 2.6),
              ("dpe_prior", "DPE centred on 5 m prior", "#2ca02c", "--", 1.3),
              ("dpe_truth", "DPE centred on truth, ±{half:g} m window (the paper's set-up, our run)", "0.45", "-.", 1.3),
              ("otdoa_first_path", "OTDoA, first-path ToA", "#d62728", "-", 1.3),
              ("otdoa_peak", "OTDoA, peak ToA (naive)", "#ff7f0e", ":", 1.6)]
    dpe_lab = ", ".join(f"{100 * q:g} % within {v:g} m" for q, v in PAPER_FIG10_DPE_M.items())
    ot_lab = ", ".join(f"{100 * q:g} % at {v:g} m" for q, v in PAPER_FIG10_OTDOA_M.items())
    with style():
        fig = Figure(figsize=(7.4, 10.4), layout="constrained")
        axes = fig.subplots(2, 1, sharex=True)
        for ax, case in zip(axes, ("two_of_four", "pr_los")):
            d = data[case]
            half = payload["config"]["experiments"][f"{case}/truth"]["half_width_m"]
            for key, lab, col, ls, lw in curves:
                q = d[key]["p50_p90_p99_m"]
                ax.step(grid, d[key]["cdf"], ls, where="post", color=col, lw=lw,
                        label=f"{lab.format(half=half)}: 90 % {q[1]:.1f} m")
            for lev in (0.9, 0.99):
                ax.axhline(lev, color="0.5", lw=0.7, ls=":")
            ax.plot(list(PAPER_FIG10_DPE_M.values()), list(PAPER_FIG10_DPE_M), **PAPER_MARKER,
                    label=f"paper (text), DPE: {dpe_lab}")
            ax.plot(list(PAPER_FIG10_OTDOA_M.values()), list(PAPER_FIG10_OTDOA_M),
                    **{**PAPER_MARKER, "markerfacecolor": "w"}, label=f"paper (text), OTDoA: {ot_lab}")
            ax.set_xscale("log")
            ax.set_xlim(0.03, 1000)
            ax.set_ylim(0, 1.0)
            ax.set_yticks(np.arange(0, 1.01, 0.1))
            ax.set_ylabel("CDF")
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("horizontal position error (m)")
            ax.set_title(titles[case], fontsize=10)
            ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, -0.14), frameon=False)
    return fig


def plot_window_study(rows: list[dict]):
    """The Fig. 9 chapter: RMSE (left) and 90 % error (right) of the honest receiver against the receiver window L.

    Parameters
    ----------
    rows : list of dict
        The rows of ``studies.urban_window_table`` (errors in metres), a line per (set-up, M).

    Returns
    -------
    matplotlib.figure.Figure
    """
    cols = sorted({(r["setup"], r["m"]) for r in rows})
    with style():
        fig = Figure(figsize=(7.4, 4.4), layout="constrained")
        axes = fig.subplots(1, 2)
        for (setup, m), col, marker in zip(cols, COLORS, "osd^v<>"):
            sel = sorted((r for r in rows if (r["setup"], r["m"]) == (setup, m)), key=lambda r: r["n_taps"])
            taps = [r["n_taps"] for r in sel]
            for ax, key in zip(axes, ("rmse_m", "p90_m")):
                ax.plot(taps, [r[key] for r in sel], marker=marker, color=col, label=f"{setup}, M = {m}")
        for ax, lab in zip(axes, ("RMSE (m)", "90 % error (m)")):
            ax.set_xscale("log", base=2)
            ax.set_yscale("log")
            ax.set_xticks(sorted({r["n_taps"] for r in rows}))
            ax.set_xticklabels([str(n) for n in sorted({r["n_taps"] for r in rows})])
            ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(FormatStrFormatter(""))
            ax.grid(True, which="both", alpha=0.3)
            ax.set_xlabel("receiver window L (taps)")
            ax.set_ylabel(lab)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=2 if max(map(len, labels)) <= 45 else 1,
                   fontsize=9, frameon=False)
    return fig


def _draw_rmse_and_bound(ax, snr, m_values, curves: dict, bound, styles=("-", "--", "-.")) -> None:
    """RMSE curves {label: (S, J)} (one colour per M, one line style per curve) and the bound (S, J) dotted, on a
    log axis with labelled ticks."""
    bound = np.asarray(bound)
    vals = [bound.ravel()]
    for k, (label, rmse) in enumerate(curves.items()):
        rmse = np.asarray(rmse)
        vals.append(rmse.ravel())
        for j, (m, marker, col) in enumerate(zip(m_values, "osd^v<>", COLORS)):
            ax.plot(snr, rmse[:, j], styles[k % len(styles)], marker=marker, color=col, ms=5,
                    label=f"M = {m}" if k == 0 else None)
        if label:
            ax.plot([], [], styles[k % len(styles)], color="0.3", label=label)
    for j, col in zip(range(bound.shape[1]), COLORS):
        ax.plot(snr, bound[:, j], ":", color=col, lw=2)
    ax.plot([], [], ":", color="0.3", lw=2, label="Cramér–Rao bound (tap delays known)")
    vals = np.concatenate(vals)
    log_ticks(ax, vals.min() / 1.3, vals.max() * 1.3)


def plot_rmse_and_bound(payload: dict):
    """The bounds chapter (not in the paper): receivers' RMSE against the per-sample SNR beside the Cramér–Rao bound.

    Parameters
    ----------
    payload : dict
        ``"snrs_db"`` (S,), ``"m_values"`` (J,) (a colour each), ``"curves"`` {label: (S, J) RMSE, metres} drawn solid,
        dashed, …, ``"bound_m"`` (S, J), metres, drawn dotted; log axis.

    Returns
    -------
    matplotlib.figure.Figure
    """
    snr = np.asarray(payload["snrs_db"])
    with style():
        fig = Figure(figsize=(7.4, 5.4), layout="constrained")
        ax = fig.subplots()
        _draw_rmse_and_bound(ax, snr, payload["m_values"], payload["curves"], payload["bound_m"])
        ax.set_xlabel("SNR per time-domain sample, before correlation (dB)")
        ax.set_ylabel("RMSE of the horizontal position (m)")
        ax.set_xticks(snr)
        ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
    return fig


#: the mark of each verdict of ``intervals.VERDICTS`` in the readings table and its Markdown
VERDICT_MARKS = {"reproduces": "✓", "unresolved": "?", "fails": "✗"}


def format_claim(claim_id: str, value: float) -> str:
    """A claim's value as the readings table prints it: metres, a ratio, or a percentage.

    Parameters
    ----------
    claim_id : str
        The claim (a key of ``readings.CLAIMS``); sets the unit.
    value : float
        The value (metres, a ratio, or a fraction printed as a percentage).

    Returns
    -------
    str
    """
    if claim_id in ("fig9_falls", "fig9_more_hurts"):
        return f"{value:.2f}×"
    if claim_id in ("fig9_saturation", "fig10_gain"):
        return f"{100 * value:.0f} %" if abs(value) >= 1 else f"{100 * value:.1f} %"
    return f"{value:.0f} m" if value >= 100 else f"{value:.1f} m" if value >= 10 else f"{value:.2f} m"


def plot_readings(payload: dict):
    """The readings table (the reproduction chapter): a column per reading of the paper, a row per claim of Figs. 9–10.

    Each cell holds its value with its verdict (``VERDICT_MARKS``): ✓ blue where the value's 95 % interval meets the
    claim, ✗ orange where it misses it, ? white where the interval straddles the claim's bound (unresolved); the mark
    carries the verdict without the colour.  Two grey rows below give the share of each reading's DPE fixes on its
    search window's edge (Fig. 9 over its cells, Fig. 10).

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.readings_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    claims, data = payload["config"]["claims"], payload["data"]
    ids, names = payload["config"]["claim_order"], payload["config"]["reading_order"]
    edge_rows = (("fig9", "Fig. 9: DPE fixes\non the window's edge"), ("fig10_dpe", "Fig. 10: DPE fixes\non the edge"))
    level = {"fails": 0.0, "unresolved": 2 / 3, "reproduces": 1.0}
    ok = np.array([[level[data[n]["verdicts"][c]] for n in names] for c in ids] + [[1 / 3] * len(names)] * len(edge_rows),
                  dtype=float)  # (claim + edge rows, reading): colour levels of fails, edge rows, unresolved, reproduces

    def two_lines(claim_id, value, mark):  # the number above its unit and mark: narrow columns
        text = format_claim(claim_id, value)
        num, unit = text.rsplit(" ", 1) if " " in text else (text[:-1], text[-1])
        return f"{num}\n{unit} {mark}"

    with style():
        fig = Figure(figsize=(7.5, 0.5 * len(ok) + 2.2), layout="constrained")
        ax = fig.subplots()
        ax.imshow(ok, cmap=ListedColormap(["#fdd0a2", "#e5e5e5", "#ffffff", "#c6dbef"]), vmin=0, vmax=1,
                  aspect="auto")
        for j, n in enumerate(names):
            for i, c in enumerate(ids):
                ax.text(j, i, two_lines(c, data[n]["values"][c], VERDICT_MARKS[data[n]["verdicts"][c]]), ha="center",
                        va="center", fontsize=9)
            for i, (key, _) in enumerate(edge_rows, len(ids)):
                ax.text(j, i, f"{100 * data[n]['edge_share'][key]:.1f}\n%", ha="center", va="center", fontsize=9)
        ax.set_yticks(range(len(ok)), [claims[c]["short"] for c in ids] + [label for _, label in edge_rows],
                      fontsize=9)
        ax.set_xticks(range(len(names)), [data[n]["short"] for n in names], rotation=60, ha="left",
                      rotation_mode="anchor", fontsize=9)
        ax.xaxis.tick_top()
        ax.set_xticks(np.arange(len(names) + 1) - 0.5, minor=True)
        ax.set_yticks(np.arange(len(ok) + 1) - 0.5, minor=True)
        ax.grid(which="major", visible=False)
        ax.grid(which="minor", color="w", lw=2)
        ax.axhline(len(ids) - 0.5, color="k", lw=1)
        ax.tick_params(which="both", length=0)
        ax.set_xlabel("✓ blue: the value's 95 % interval meets the claim;  ✗ orange: it misses it;\n? white: "
                      "unresolved (the interval straddles the claim's bound);\ngrey: the share of DPE fixes on the "
                      "search window's edge", fontsize=9)
    return fig


def plot_p90_sweep(payload: dict):
    """The NLoS-bias chapter: 90 % error (log axis) with its 95 % bootstrap interval against a swept setting.

    Parameters
    ----------
    payload : dict
        ``"x"`` (K,), ``"xlabel"``, ``"panels"`` {title (a panel per case): {receiver (a line each): {``"p90_m"``,
        ``"lo_m"``, ``"hi_m"``: (K,) metres}}}, ``"marks"`` {label: metres} (the paper's stated values, dotted).

    Returns
    -------
    matplotlib.figure.Figure
    """
    x = np.asarray(payload["x"], dtype=float)
    panels = payload["panels"]
    styles = ("-o", "--s", "-.d", "-^", ":v")
    with style():
        fig = Figure(figsize=(7.4, 3.9 * len(panels) + 0.9), layout="constrained")
        axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
        for ax, (title, curves) in zip(axes, panels.items()):
            for (label, c), col, st in zip(curves.items(), COLORS, styles):
                p90 = np.asarray(c["p90_m"])
                err = [p90 - np.asarray(c["lo_m"]), np.asarray(c["hi_m"]) - p90]
                ax.errorbar(x, p90, yerr=err, fmt=st, color=col, ms=5, capsize=3, label=label)
            for (label, v), col in zip(payload.get("marks", {}).items(), ("k", "0.4")):
                ax.axhline(v, color=col, lw=1.0, ls=":", label=label)
            vals = [v for c in curves.values() for k in ("lo_m", "hi_m") for v in c[k]]
            vals += list(payload.get("marks", {}).values())
            log_ticks(ax, min(vals) / 1.3, max(vals) * 1.3)
            ax.set_xticks(x)
            ax.set_title(textwrap.fill(title, 90), fontsize=10)
            ax.set_ylabel("90 % error (m)")
            ax.xaxis.set_tick_params(labelbottom=True)
        axes[-1].set_xlabel(payload["xlabel"])
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=2 if max(map(len, labels)) <= 45 else 1,
                   fontsize=9, frameon=False)
    return fig


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
