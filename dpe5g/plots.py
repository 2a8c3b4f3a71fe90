"""Drawing of the paper's figures from their data (never from live computation).

Each ``plot_*`` function takes the JSON-able payload that ``dpe5g.figures`` computed and returns a matplotlib
Figure (created without pyplot, so no backend or global figure state is involved), so a figure can be redrawn from ``figures/data/<id>.json`` alone.  All figures use matplotlib's "default"
style and the DejaVu Sans font bundled with matplotlib, so pixels depend only on the pinned matplotlib version.
"""

from __future__ import annotations

import contextlib

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import patheffects
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator, FormatStrFormatter, MultipleLocator, NullFormatter

#: rcParams on top of matplotlib's "default" style.  Fixed font and hinting keep PNGs byte-stable per version.
RC = {
    "font.family": "DejaVu Sans",
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.35,
    "figure.dpi": 100,
    "savefig.dpi": 100,
    "text.hinting": "default",
    "svg.hashsalt": "dpe5g",
    "path.simplify": False,
}


@contextlib.contextmanager
def style():
    """Context with the project's plotting style."""
    with plt.style.context("default"), matplotlib.rc_context(RC):
        yield


def save_png(fig, path) -> None:
    """Write ``fig`` as PNG with no timestamp or software metadata (byte-stable for the same inputs)."""
    fig.savefig(path, format="png", metadata={"Software": None})


def plot_tdl(payload: dict):
    """Figs. 1–5: (a) one realised CIR of a TDL profile, (b) its normalized PDP.

    (a) shows |h_l| of each drawn tap at its delay (stems; the specular LoS component of TDL-D/E in red) and the
    magnitude of the band-limited CIR the receiver sees on its 8.14 ns sample grid (crosses).
    (b) shows the mean tap powers 10 log10(P_l / max P) in dB against delay.
    """
    d = payload["data"]
    cfg = payload["config"]
    delays_ns = np.asarray(d["delays_ns"])
    gains = np.asarray(d["gains_re"]) + 1j * np.asarray(d["gains_im"])
    los = np.asarray(d["los"], dtype=bool)
    pdp = np.asarray(d["pdp_db"])
    t_ns = np.asarray(d["grid_ns"])
    cir = np.asarray(d["grid_abs"])
    with style():
        fig = Figure(figsize=(8.0, 3.0), layout="constrained")
        ax_a, ax_b = fig.subplots(1, 2)
        nlos = ~los
        ml, _, _ = ax_a.stem(delays_ns[nlos], np.abs(gains[nlos]), basefmt=" ", label="taps |$h_l$|")
        ml.set_markersize(4)
        if los.any():
            ml2, _, _ = ax_a.stem(delays_ns[los], np.abs(gains[los]), linefmt="C3-", markerfmt="C3o", basefmt=" ",
                                  label="LoS (specular)")
            ml2.set_markersize(5)
        ax_a.plot(t_ns, cir, "x", color="C2", markersize=4, label=f"sampled CIR |h[n]|, T$_s$ = {d['ts_ns']:.2f} ns")
        ax_a.set_xlabel("delay (ns)")
        ax_a.set_ylabel("amplitude")
        ax_a.set_title(f"(a) CIR, one draw (seed {payload['seed']})")
        ax_a.legend(fontsize=7, loc="upper right")
        ax_b.stem(delays_ns, pdp, bottom=-40, basefmt=" ")
        ax_b.set_ylim(-40, 3)
        ax_b.set_xlabel("delay (ns)")
        ax_b.set_ylabel("normalized power (dB)")
        ax_b.set_title(f"(b) normalized PDP, RMS DS {d['rms_ds_ns']:.1f} ns")
        for ax in (ax_a, ax_b):
            ax.set_xlim(-0.04 * delays_ns.max() - 5, 1.04 * delays_ns.max() + 5)
        fig.suptitle(f"{cfg['profile_name']} ({cfg['table']}), desired DS {cfg['delay_spread_s'] * 1e9:g} ns",
                     fontsize=10)
    return fig


def plot_cost_surface(payload: dict):
    """Fig. 6: eq. (10) normalized to its maximum over (x, y), (a) as a map, (b) cuts through the peak."""
    d = payload["data"]
    cfg = payload["config"]
    x, y = np.asarray(d["x_m"]), np.asarray(d["y_m"])
    c = np.asarray(d["cost_norm"])
    ue = cfg["ue_xyz"]
    with style():
        fig = Figure(figsize=(8.0, 3.9), layout="constrained")
        fig.get_layout_engine().set(wspace=0.08)  # room between the colorbar's label and (b)'s y label
        ax_a, ax_b = fig.subplots(1, 2)
        im = ax_a.pcolormesh(x, y, c, shading="nearest", cmap="viridis", vmin=0, vmax=1)
        fig.colorbar(im, ax=ax_a, label="normalized cost")
        ax_a.plot(*d["peak_xy"], "wx", markersize=8, mew=1.5, label="grid maximum",
                  path_effects=[patheffects.withStroke(linewidth=3, foreground="k")])
        ax_a.plot(ue[0], ue[1], "r+", markersize=12, mew=2, label="true position")
        ax_a.set_xlabel("x (m)")
        ax_a.set_ylabel("y (m)")
        ax_a.set_aspect("equal")
        # below the map, not on it (the map has no empty corner)
        handles, labels = ax_a.get_legend_handles_labels()
        ax_a.legend(handles[::-1], labels[::-1], fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2,
                    frameon=False)
        ax_a.set_title(f"(a) eq. (10), {cfg['n_bs']} BSs, L = {cfg['n_taps_receiver']} taps")
        iy = int(np.argmin(np.abs(y - ue[1])))
        ix = int(np.argmin(np.abs(x - ue[0])))
        ax_b.plot(x, c[iy, :], label="cut along x")
        ax_b.plot(y, c[:, ix], "--", label="cut along y")
        ax_b.axvline(0.0, color="r", lw=0.8)
        ax_b.set_xlabel("offset from true position (m)")
        ax_b.set_ylabel("normalized cost")
        ax_b.set_title("(b) cuts through the true position")
        ax_b.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    return fig


def place_texts(fig, ax, texts, markers=(), pad_px: float = 1.5) -> None:
    """Greedy, deterministic placement of labels so that no two overlap and none leaves the axes.

    texts : list of (Text, candidates), each candidate a dict of Text properties (``position``, ``ha``, ``va``, ...);
        the texts are placed in order, each at its first candidate whose box (grown by ``pad_px``) lies inside the
        axes and clear of the markers and of the texts placed before it; where no candidate is clear, the one with the
        least overlap.
    markers : (x, y, half_size_pt) in data coordinates: squares no label may cover.
    The layout is done first (``fig.draw_without_rendering``) and the texts are kept out of it (``in_layout`` off), so
    the boxes measured here are where the texts are drawn (up to the layout's last sub-pixel adjustments, which
    ``pad_px`` absorbs).
    """
    from matplotlib.transforms import Bbox

    for t, _ in texts:
        t.set_in_layout(False)
    fig.draw_without_rendering()
    frame = ax.get_window_extent()
    placed = []
    for x, y, half in markers:
        h = half * fig.dpi / 72
        cx, cy = ax.transData.transform((x, y))
        placed.append(Bbox.from_extents(cx - h, cy - h, cx + h, cy + h))

    def cost(box):
        inside = frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
        hit = sum(max(0.0, min(box.x1, o.x1) - max(box.x0, o.x0)) * max(0.0, min(box.y1, o.y1) - max(box.y0, o.y0))
                  for o in placed)
        return (0.0 if inside else 1e9) + hit

    for t, candidates in texts:
        best = None
        for k, cand in enumerate(candidates):
            t.update(cand)
            box = t.get_window_extent().padded(pad_px)
            c = cost(box)
            if best is None or c < best[0]:
                best = (c, k, box)
            if c == 0.0:
                break
        t.update(candidates[best[1]])
        placed.append(best[2])


def plot_deployment(payload: dict):
    """Fig. 7: buildings (shaded by height), streets, BSs, the example UE and its links (LoS solid, NLoS dashed).

    Street names and BS numbers are placed by ``place_texts``: each street name along its street (the map's edge
    first, then the blocks between the cross streets), each BS number at one of eight spots around its marker, so
    that no two labels overlap, none covers a marker and none is cut by the map's border.
    """
    from matplotlib.patches import Rectangle

    d = payload["data"]
    x0, y0, x1, y1 = d["region"]
    with style():
        fig = Figure(figsize=(6.4, 6.3), layout="constrained")
        ax = fig.subplots()
        ax.set_facecolor("#f4f4f0")
        heights = [b[4] for b in d["buildings"]]
        cmap = matplotlib.colormaps["Greys"]
        norm = matplotlib.colors.Normalize(0, max(heights) if heights else 1)
        for bx0, by0, bx1, by1, h in d["buildings"]:
            ax.add_patch(Rectangle((bx0, by0), bx1 - bx0, by1 - by0, facecolor=cmap(0.25 + 0.6 * norm(h)),
                                   edgecolor="none"))
        sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=matplotlib.colors.ListedColormap(
            cmap(np.linspace(0.25, 0.85, 64))))
        fig.colorbar(sm, ax=ax, label="building height (m)", shrink=0.7)
        ue = d["ue_xyz"]
        for b, los in zip(d["link_bs_xyz"], d["link_los"]):
            ax.plot([ue[0], b[0]], [ue[1], b[1]], "-" if los else "--", color="#2ca02c" if los else "#ff7f0e",
                    lw=1.4 if los else 1.0, zorder=3)
        bs = np.asarray(d["bs_xyz"])
        ax.plot(bs[:, 0], bs[:, 1], "^", color="#d62728", markersize=7, markeredgecolor="k", mew=0.5, zorder=4,
                label=f"BS ({len(bs)}, 10 m, 24 dBm)")
        ax.plot(ue[0], ue[1], "o", color="#1f77b4", markersize=8, markeredgecolor="k", zorder=5, label="example UE")
        ax.plot([], [], "-", color="#2ca02c", label="LoS link")
        ax.plot([], [], "--", color="#ff7f0e", label="NLoS link")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.grid(False)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=2, frameon=False)
        c = payload["config"]
        ax.set_title(f"{c['n_bs']} BSs over {c['area_m2']:,.0f} m², example UE with its {c['m']} nearest links",
                     fontsize=10)

        # labels: street names first (they may slide along their street), then the BS numbers around their markers
        halo = [patheffects.withStroke(linewidth=2.5, foreground="w")]
        streets = sorted(d["streets"], key=lambda s: (s["axis"], s["centre_m"]))
        ns = sorted(s["centre_m"] for s in streets if s["axis"] == "north-south")
        ew = sorted(s["centre_m"] for s in streets if s["axis"] == "east-west")
        mid = lambda cuts, lo, hi: [(a + b) / 2 for a, b in zip([lo, *cuts], [*cuts, hi])]
        texts = []
        for s in streets:
            t = ax.text(0, 0, s["name"], fontsize=7.5, color="#444444", style="italic", zorder=4.5, path_effects=halo,
                        in_layout=False)
            if s["axis"] == "north-south":
                t.set_rotation(90)
                cands = [dict(position=(s["centre_m"], y1 - 4), ha="center", va="top"),
                         dict(position=(s["centre_m"], y0 + 4), ha="center", va="bottom")]
                cands += [dict(position=(s["centre_m"], yy), ha="center", va="center") for yy in mid(ew, y0, y1)[::-1]]
            else:
                cands = [dict(position=(x0 + 4, s["centre_m"]), ha="left", va="center"),
                         dict(position=(x1 - 4, s["centre_m"]), ha="right", va="center")]
                cands += [dict(position=(xx, s["centre_m"]), ha="center", va="center") for xx in mid(ns, x0, x1)]
            texts.append((t, cands))
        spots = [(1, 1, "left", "bottom"), (1, -1, "left", "top"), (-1, 1, "right", "bottom"), (-1, -1, "right", "top"),
                 (1.4, 0, "left", "center"), (-1.4, 0, "right", "center"), (0, 1.3, "center", "bottom"),
                 (0, -1.3, "center", "top")]
        for bid, (bx, by, _) in zip(d["bs_ids"], bs):
            t = ax.annotate(bid[2:], (bx, by), xytext=(0, 0), textcoords="offset points", fontsize=8, zorder=5,
                            annotation_clip=False, path_effects=halo, in_layout=False)
            cands = [dict(position=(r * sx, r * sy), ha=ha, va=va) for r in (4.0, 7.0, 11.0) for sx, sy, ha, va in spots]
            texts.append((t, cands))
        place_texts(fig, ax, texts, [(bx, by, 4.5) for bx, by, _ in bs] + [(ue[0], ue[1], 5.0)])
    return fig


def plot_urban_correlogram(payload: dict):
    """Fig. 8: the summed correlogram around the example UE with the truth and the DPE fix."""
    d = payload["data"]
    c = payload["config"]
    x, y = np.asarray(d["x_m"]), np.asarray(d["y_m"])
    ue, est = d["ue_xyz"], d["est_xyz"]
    with style():
        fig = Figure(figsize=(6.2, 5.3), layout="constrained")
        ax = fig.subplots()
        cost = np.asarray(d["cost_norm"])
        im = ax.pcolormesh(x - ue[0], y - ue[1], cost, shading="nearest", cmap="viridis", vmin=cost.min(), vmax=1)
        fig.colorbar(im, ax=ax, label="normalized cost, eq. (10)")
        ax.plot(0, 0, "r+", markersize=14, mew=2, label="ground truth")
        ax.plot(est[0] - ue[0], est[1] - ue[1], ls="none", marker="X", markersize=10, mfc="white", mec="k", mew=1.0,
                label=f"DPE fix ({d['error_m']:.2f} m off)")
        ax.set_xlabel("east offset from the UE (m)")
        ax.set_ylabel("north offset from the UE (m)")
        ax.set_aspect("equal")
        ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, frameon=False)
        ax.set_title(f"{c['m']} nearest BSs ({d['n_los']} LoS), {c['snr_db']:g} dB, L = {c['n_taps']}")
    return fig


COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


#: Values the paper states in its text (Section IV), drawn on Figs. 9 and 10 as black-edged stars (``PAPER_MARKER``;
#: no curve of ours uses a star) labelled "paper (text)".
#: Only what the sentences say: Fig. 9 gives one point (M = 6, 10 dB, "within 6 m") and "sub-meter" without an SNR or M;
#: Fig. 10 gives DPE's 90 % and 99 % points and OTDoA's 90 % point.
PAPER_FIG9_RMSE_M = {"m": 6, "snr_db": 10.0, "rmse_m": 6.0}  # "an overall RMSE constrained within 6 m, even in the
#   worst simulation scenario where only 6 candidate BSs are used and the SNR is as low as 10 dB"
PAPER_FIG9_SUB_METRE_M = 1.0  # "As the number of available positioning sources increases, a sub-meter positioning
#   accuracy can be achieved, particularly when the propagation environment provides a high signal quality"
PAPER_FIG10_DPE_M = {0.9: 2.0, 0.99: 7.0}  # "the RMSE obtained by 5G DPE can be constrained within 7 m for 99% of the
#   use cases, with a 90% probability of achieving an RMSE within 2 m"
PAPER_FIG10_OTDOA_M = {0.9: 42.0}  # "the conventional OTDoA method results in a 42-meter RMSE for 90% of the use cases"
PAPER_MARKER = dict(marker="*", color="k", markersize=13, markerfacecolor="#ffd500", markeredgecolor="k", mew=1.0,
                    ls="none", zorder=6, clip_on=False)


def log_ticks(ax, lo: float, hi: float) -> None:
    """A log y axis over [lo, hi] with enough labelled ticks to read values off.

    Within about a decade and a half: labels at 1, 1.2, 1.5, 2, 3, 4, 5, 6, 8 × 10^k and a light minor grid in
    between (steps of 0.1 × 10^k up to 2 × 10^k), so a value reads to 0.1 m around 1 m.  Up to three decades: labels
    at 1, 2, 5 × 10^k, minor grid at the other integers.  Wider: labels at the decades.
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


def plot_rmse_vs_snr(payload: dict):
    """Fig. 9: RMSE of the horizontal error against the per-sample SNR, one colour per M; solid: the honest
    receiver (window on a prior, certified search), dashed: the paper's truth-centred grid.  A payload with one
    receiver only (the chapters' studies) is drawn solid.  Where the SNR axis holds 10 dB and M = 6 is drawn, the
    values the paper's text states are drawn as well (``PAPER_FIG9_*``)."""
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
            axb.set_title(f"(b) honest receiver (solid), Cramér–Rao bound (dotted, {c['bound_trials']} trials)",
                          fontsize=10)
            axb.set_xlabel("SNR per time-domain sample, before correlation (dB)")
            axb.set_ylabel("RMSE (m)")
            axb.set_xticks(snr)
    return fig


def plot_cdf(payload: dict):
    """Fig. 10: error CDFs of the DPE receivers and of OTDoA; left the paper's case (2 of 4 links LoS), right LoS
    from eq. (11).  Both panels carry the points the paper's text states (``PAPER_FIG10_*``) as stars."""
    grid = np.asarray(payload["config"]["error_grid_m"])
    data = payload["data"]
    titles = {"two_of_four": "(a) 2 of 4 links LoS (paper's case)", "pr_los": "(b) LoS from eq. (11)"}
    curves = [("dpe_otdoa", "DPE centred on OTDoA fix", "#1f77b4", "-"),
              ("dpe_prior", "DPE centred on 5 m prior", "#2ca02c", "-"),
              ("dpe_truth", "DPE centred on truth (paper)", "0.45", "--"),
              ("otdoa_first_path", "OTDoA, first-path ToA", "#d62728", "-"),
              ("otdoa_peak", "OTDoA, peak ToA (naive)", "#ff7f0e", ":")]
    dpe_lab = ", ".join(f"{100 * q:g} % within {v:g} m" for q, v in PAPER_FIG10_DPE_M.items())
    ot_lab = ", ".join(f"{100 * q:g} % at {v:g} m" for q, v in PAPER_FIG10_OTDOA_M.items())
    with style():
        fig = Figure(figsize=(10.0, 5.6), layout="constrained")
        axes = fig.subplots(1, 2, sharey=True)
        for ax, case in zip(axes, ("two_of_four", "pr_los")):
            d = data[case]
            for key, lab, col, ls in curves:
                q = d[key]["p50_p90_p99_m"]
                ax.step(grid, d[key]["cdf"], ls, where="post", color=col, label=f"{lab}: 90 % {q[1]:.1f} m")
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
            ax.set_xlabel("horizontal position error (m)")
            ax.set_title(titles[case], fontsize=10)
            ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(0.0, -0.12), frameon=False)
        axes[0].set_ylabel("CDF")
    return fig


def plot_plateau(payload: dict):
    """Chapter 3: one BS term of eq. (10) against the candidate ToA offset c (τ − τ₀) for a TDL-D (LoS) and a TDL-C
    (NLoS) link and several windows L (``studies.plateau_payload``), with the link's sampled CIR power as grey
    stems.  A window of L taps sums the CIR power over [τ, τ + (L − 1) T_s], so where one tap holds the energy the
    cost is flat for (L − 1) T_s before the first path and falls off a cliff after it."""
    d, c = payload["data"], payload["config"]
    x = np.asarray(d["offset_m"])
    titles = {"TDL-D": "TDL-D (LoS, K = {:g} dB)".format(c["k_factor_db"]), "TDL-C": "TDL-C (NLoS)"}
    with style():
        fig = Figure(figsize=(9.0, 4.0), layout="constrained")
        axes = fig.subplots(1, 2, sharey=True)
        for ax, name in zip(axes, ("TDL-D", "TDL-C")):
            p = d[name]
            keep = np.asarray(p["cir_offset_m"]) <= x.max()
            ax.vlines(np.asarray(p["cir_offset_m"])[keep], 0, np.asarray(p["cir_power"])[keep], color="0.6", lw=2.5,
                      label="sampled CIR power |h[n]|²")
            for n, col in zip(c["taps"], COLORS):
                plateau = (n - 1) * c["sample_m"]
                lab = f"L = {n}" + (f" (plateau {plateau:.1f} m)" if n > 1 else "")
                ax.plot(x, d[name]["cost"][str(n)], color=col, lw=1.4, label=lab)
            ax.axvline(0.0, color="k", lw=0.8, ls=":")
            ax.set_xlim(x.min(), x.max())
            ax.set_ylim(0, 1.05)
            ax.set_xlabel("candidate ToA offset c(τ − τ₀) (m)")
            ax.set_title(titles[name], fontsize=9)
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
        axes[0].set_ylabel("cost of one link / its maximum")
    return fig


def plot_window_study(rows: list[dict]):
    """Chapter 5: RMSE (left) and 90 % error (right) of the honest receiver against the receiver window L, one line
    per (set-up, M) of ``studies.urban_window_table``."""
    cols = sorted({(r["setup"], r["m"]) for r in rows})
    with style():
        fig = Figure(figsize=(9.0, 3.8), layout="constrained")
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
            from matplotlib.ticker import FormatStrFormatter, LogLocator

            ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(FormatStrFormatter(""))
            ax.grid(True, which="both", alpha=0.3)
            ax.set_xlabel("receiver window L (taps)")
            ax.set_ylabel(lab)
        axes[1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
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
    """Chapter 8 (not in the paper): RMSE of receivers against the per-sample SNR beside the Cramér–Rao bound, log
    axis, one colour per M.  payload: snrs_db (S,), m_values (J,), curves {label: (S, J) RMSE in m} drawn solid,
    dashed, …, bound (S, J) in m drawn dotted."""
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


def format_claim(claim_id: str, value: float) -> str:
    """A claim's value as the readings table prints it: metres, a ratio, or a percentage."""
    if claim_id in ("fig9_falls", "fig9_more_hurts"):
        return f"{value:.2f}×"
    if claim_id in ("fig9_saturation", "fig10_gain"):
        return f"{100 * value:.1f} %"
    return f"{value:.1f} m" if value >= 10 else f"{value:.2f} m"


def plot_readings(payload: dict):
    """The readings table (Chapter 7): one row per reading of the paper, one column per claim of Figs. 9–10, each
    cell its value, green where it meets the claim and red where it differs."""
    claims, data = payload["config"]["claims"], payload["data"]
    ids, names = payload["config"]["claim_order"], payload["config"]["reading_order"]
    ok = np.array([[data[n]["reproduced"][c] for c in ids] for n in names], dtype=float)
    with style():
        fig = Figure(figsize=(12.0, 0.55 * len(names) + 2.6), layout="constrained")
        ax = fig.subplots()
        ax.imshow(ok, cmap=matplotlib.colors.ListedColormap(["#f4c7c3", "#c6e9c6"]), vmin=0, vmax=1, aspect="auto")
        for i, n in enumerate(names):
            for j, c in enumerate(ids):
                ax.text(j, i, format_claim(c, data[n]["values"][c]), ha="center", va="center", fontsize=9)
        ax.set_xticks(range(len(ids)), [claims[c]["short"] for c in ids], rotation=30, ha="right", fontsize=9)
        ax.set_yticks(range(len(names)), [data[n]["short"] for n in names], fontsize=9)
        ax.set_xticks(np.arange(len(ids) + 1) - 0.5, minor=True)
        ax.set_yticks(np.arange(len(names) + 1) - 0.5, minor=True)
        ax.grid(which="major", visible=False)
        ax.grid(which="minor", color="w", lw=2)
        ax.tick_params(which="both", length=0)
        ax.set_title("Which reading of the paper reproduces which claim (green: reproduced, red: differs)",
                     fontsize=10)
    return fig


def plot_link_sinr(groups: dict):
    """Chapter 4: CDF of the per-link SNR (dashed) and SINR with PRS reuse (solid), one colour per group of links.
    groups : {label: {"snr_db": array, "sinr_db": array}} (per-sample dB, any shape, flattened)."""
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
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig


def plot_reuse_rmse(payload: dict):
    """Chapter 5: RMSE against the nearest link's per-sample SNR for each M, one panel per set-up of the payload
    {"snrs_db", "m_values", "setups": {label: (S, J) RMSE}} (the same trials in every panel), log axis."""
    snr = np.asarray(payload["snrs_db"])
    setups = payload["setups"]
    vals = np.concatenate([np.ravel(v) for v in setups.values()])
    with style():
        fig = Figure(figsize=(3.3 * len(setups) + 0.6, 4.2), layout="constrained")
        axes = np.atleast_1d(fig.subplots(1, len(setups), sharey=True))
        for ax, (label, rmse) in zip(axes, setups.items()):
            rmse = np.asarray(rmse)
            for j, (m, marker, col) in enumerate(zip(payload["m_values"], "osd^v<>", COLORS)):
                ax.plot(snr, rmse[:, j], "-", marker=marker, color=col, label=f"M = {m}")
            ax.set_title(label, fontsize=9)
            ax.set_xticks(snr)
            ax.set_xlabel("SNR of the nearest link (dB)")
            log_ticks(ax, vals.min() / 1.15, vals.max() * 1.15)
        axes[0].set_ylabel("RMSE (m)")
        axes[-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig


def plot_reuse_cdf(payload: dict):
    """Chapter 6: error CDFs of the OTDoA-centred DPE (solid) and first-path OTDoA (dashed) with and without PRS reuse,
    one panel per LoS case.  payload {"cases": {case: {label: {"dpe": errors, "otdoa": errors}}}}."""
    titles = {"two_of_four": "(a) 2 of 4 links LoS (paper's case)", "pr_los": "(b) LoS from eq. (11)"}
    n_cases = len(payload["cases"])
    if n_cases == 0:
        raise ValueError("plot_reuse_cdf: payload['cases'] is empty, need at least one LoS case")
    with style():
        fig = Figure(figsize=(5.0 * n_cases + (1.5 if n_cases == 1 else 0.0), 4.8), layout="constrained")
        axes = np.atleast_1d(fig.subplots(1, n_cases, sharey=True))
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
            ax.set_title(titles.get(case, case), fontsize=10)
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.14), frameon=False)
        axes[0].set_ylabel("CDF")
    return fig
