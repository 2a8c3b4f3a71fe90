"""Drawing of the paper's figures from their data (never from live computation): the style every figure shares,
and the figures of the channel, the cost and the scenario (Figs. 1–8, the DPE chapter's plateau); the Monte Carlo
results (Figs. 9–10, the readings, the studies) are drawn by ``result_plots``.

Each ``plot_*`` function takes the JSON-able payload that ``dpe5g.figures.registry`` computed and returns a matplotlib
Figure (created without pyplot, so no backend or global figure state is involved), so a figure can be redrawn from
``figures/data/<id>.json`` alone.  All figures use matplotlib's "default" style and the DejaVu Sans font bundled with
matplotlib, so pixels depend only on the pinned matplotlib version.

Legibility: the book shows a figure at its own size up to its 768-pixel column, so a figure at most ``MAX_WIDTH_IN``
wide (at 100 dpi) is never shrunk, and text of ``MIN_FONT_PT`` is 9 pt on the page.  ``check_legible`` enforces both
when a figure is saved (``save_png``) or handed to a chapter (``figures.glue``).
"""

from __future__ import annotations

import contextlib

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import patheffects
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.text import Text
from matplotlib.transforms import Bbox

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


#: the smallest text of any figure (pt), and the widest figure (inches at RC's 100 dpi: the book's 768-pixel column)
MIN_FONT_PT = 9.0
MAX_WIDTH_IN = 7.68


def check_legible(fig) -> None:
    """Check that the book shows ``fig`` unshrunk with every text legible.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure, drawn (without rendering) here to measure it.

    Raises
    ------
    ValueError
        When a visible text is smaller than ``MIN_FONT_PT``, or the figure, as saved (its size) or as the book shows it
        (its drawn extent plus the 0.1-inch margins of a tight crop), is wider than ``MAX_WIDTH_IN``.
    """
    fig.draw_without_rendering()
    small = [(t.get_fontsize(), t.get_text()) for t in fig.findobj(Text)
             if t.get_visible() and t.get_text().strip() and t.get_fontsize() < MIN_FONT_PT]
    if small:
        size, text = min(small)
        raise ValueError(f"figure text {text!r} is {size:g} pt; every text must be at least {MIN_FONT_PT:g} pt "
                         f"({len(small)} smaller)")
    width = max(fig.get_figwidth(), fig.get_tightbbox().width + 2 * matplotlib.rcParams["savefig.pad_inches"])
    if width > MAX_WIDTH_IN:
        raise ValueError(f"figure is {width:.2f} in wide; at most {MAX_WIDTH_IN} in is shown without shrinking its text")


@contextlib.contextmanager
def style():
    """Context with the project's plotting style: matplotlib's "default" style with ``RC`` on top.

    Yields
    ------
    None
        Figures created inside the context take the style.
    """
    with plt.style.context("default"), matplotlib.rc_context(RC):
        yield


def save_png(fig, path) -> None:
    """Write ``fig`` as PNG with no timestamp or software metadata (byte-stable for the same inputs).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str, pathlib.Path or file object
        Where to write it (the format is PNG whatever the name).

    Raises
    ------
    ValueError
        When ``check_legible`` fails on ``fig`` (checked before anything is written).
    """
    check_legible(fig)
    fig.savefig(path, format="png", metadata={"Software": None})


def plot_tdl(payload: dict):
    """Figs. 1–5: (a) one realised CIR of a TDL profile, (b) its normalized PDP.

    (a) shows ``|h_l|`` of each drawn tap at its delay (stems; the specular LoS component of TDL-D/E in red) and the
    magnitude of the band-limited CIR the receiver sees on its 8.14 ns sample grid (crosses).
    (b) shows the mean tap powers 10 log10(P_l / max P) in dB against delay.

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.tdl_payload``.

    Returns
    -------
    matplotlib.figure.Figure
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
        fig = Figure(figsize=(7.4, 4.1), layout="constrained")
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
        ax_a.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=1, frameon=False)
        ax_b.stem(delays_ns, pdp, bottom=-40, basefmt=" ")
        ax_b.set_ylim(-40, 3)
        ax_b.set_xlabel("delay (ns)")
        ax_b.set_ylabel("normalized power (dB)")
        ax_b.set_title(f"(b) normalized PDP, RMS DS {d['rms_ds_ns']:.1f} ns")
        # (a) spans the delays that hold 99 % of the drawn power (at least 200 ns), so the taps near 0 are apart;
        # the weak late taps are in (b), which spans them all
        shown = cir_span_ns(delays_ns, np.abs(gains) ** 2)
        ax_a.set_xlim(-0.04 * shown - 5, 1.04 * shown)
        beyond = delays_ns > shown
        if beyond.any():
            ax_a.text(0.98, 0.96, f"{beyond.sum()} weaker taps up to\n{delays_ns.max():.0f} ns: see (b)",
                      transform=ax_a.transAxes, ha="right", va="top", fontsize=9)
        ax_b.set_xlim(-0.04 * delays_ns.max() - 5, 1.04 * delays_ns.max() + 5)
        fig.suptitle(f"{cfg['profile_name']} ({cfg['table']}), desired DS {cfg['delay_spread_s'] * 1e9:g} ns",
                     fontsize=10)
    return fig


def cir_span_ns(delays_ns, power, share: float = 0.99, floor_ns: float = 200.0) -> float:
    """The span of the TDL figures' panel (a): the delay by which the taps hold ``share`` of the total power.

    Parameters
    ----------
    delays_ns : float (n_taps,)
        The taps' delays, nanoseconds.
    power : float (n_taps,)
        The taps' powers (any linear unit).
    share : float
        The share of the total power to hold, 0 to 1.
    floor_ns : float
        The least span, nanoseconds.

    Returns
    -------
    float
        The delay, nanoseconds, rounded up to 50 ns and at least ``floor_ns``.
    """
    order = np.argsort(delays_ns)
    cum = np.cumsum(np.asarray(power)[order]) / np.sum(power)
    t = float(np.asarray(delays_ns)[order][min(int(np.searchsorted(cum, share)), len(cum) - 1)])
    return max(floor_ns, 50.0 * np.ceil(t / 50.0))


def plot_cost_surface(payload: dict):
    """Fig. 6: eq. (10) normalized to its maximum over (x, y), (a) as a map, (b) cuts through the peak.

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.cost_surface_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = payload["data"]
    cfg = payload["config"]
    x, y = np.asarray(d["x_m"]), np.asarray(d["y_m"])
    c = np.asarray(d["cost_norm"])
    ue = cfg["ue_xyz"]
    with style():
        fig = Figure(figsize=(7.3, 4.0), layout="constrained")
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
        ax_b.set_title("(b) cuts through the truth")
        ax_b.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    return fig


def place_texts(fig, ax, texts, markers=(), pad_px: float = 1.5) -> None:
    """Greedy, deterministic placement of labels so that no two overlap and none leaves the axes.

    The layout is done first (``fig.draw_without_rendering``) and the texts are kept out of it (``in_layout`` off), so
    the boxes measured here are where the texts are drawn (up to the layout's last sub-pixel adjustments, which
    ``pad_px`` absorbs).  ``plot_deployment`` places each street name along its street (the map's edge first, then
    the blocks between the cross streets) and each BS number at one of eight spots around its marker, so that no two
    labels overlap, none covers a marker and none is cut by the map's border.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure holding ``ax``.
    ax : matplotlib.axes.Axes
        The axes the labels must stay inside.
    texts : list of (matplotlib.text.Text, candidates)
        Each candidate a dict of Text properties (``position``, ``ha``, ``va``, ...).  The texts are placed in order,
        each at its first candidate whose box (grown by ``pad_px``) lies inside the axes and clear of the markers and
        of the texts placed before it; where no candidate is clear, at the one with the least overlap.
    markers : sequence of (x, y, half_size_pt)
        Squares no label may cover: centre in data coordinates, half side in points.
    pad_px : float
        Margin added around each text's box, pixels.
    """
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

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.deployment_payload``; street names and BS numbers are placed by ``place_texts``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = payload["data"]
    x0, y0, x1, y1 = d["region"]
    with style():
        fig = Figure(figsize=(7.4, 7.3), layout="constrained")
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
                label=f"BS ({len(bs)}, 10 m, 24 dBm)", clip_on=False)  # masts on the map's edge drawn whole
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
            t = ax.text(0, 0, s["name"], fontsize=9, color="#444444", style="italic", zorder=4.5, path_effects=halo,
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
            t = ax.annotate(bid[2:], (bx, by), xytext=(0, 0), textcoords="offset points", fontsize=9, zorder=5,
                            annotation_clip=False, path_effects=halo, in_layout=False)
            cands = [dict(position=(r * sx, r * sy), ha=ha, va=va) for r in (4.0, 7.0, 11.0) for sx, sy, ha, va in spots]
            texts.append((t, cands))
        place_texts(fig, ax, texts, [(bx, by, 4.5) for bx, by, _ in bs] + [(ue[0], ue[1], 5.0)])
    return fig


def plot_urban_correlogram(payload: dict):
    """Fig. 8: the summed correlogram around the example UE with the truth and the DPE fix.

    Parameters
    ----------
    payload : dict
        The payload of ``figure_data.urban_correlogram_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = payload["data"]
    c = payload["config"]
    x, y = np.asarray(d["x_m"]), np.asarray(d["y_m"])
    ue, est = d["ue_xyz"], d["est_xyz"]
    with style():
        fig = Figure(figsize=(6.2, 5.3), layout="constrained")
        ax = fig.subplots()
        cost = np.asarray(d["cost_norm"])
        im = ax.pcolormesh(x - ue[0], y - ue[1], cost, shading="nearest", cmap="viridis", vmin=0, vmax=1)  # as Fig. 6
        fig.colorbar(im, ax=ax, label="normalized cost, eq. (10)")
        ax.plot(0, 0, "r+", markersize=14, mew=2, label="ground truth")
        ax.plot(est[0] - ue[0], est[1] - ue[1], ls="none", marker="X", markersize=10, mfc="white", mec="k", mew=1.0,
                label=f"DPE fix ({d['error_m']:.2f} m off)")
        ax.set_xlabel("east offset from the UE (m)")
        ax.set_ylabel("north offset from the UE (m)")
        ax.set_aspect("equal")
        ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, frameon=False)
        ax.set_title(f"{c['m']} nearest BSs ({d['n_los']} LoS), {c['snr_db']:g} dB, receiver window of {c['n_taps']} taps")
    return fig


COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


def plot_plateau(payload: dict):
    """The DPE chapter: one BS term of eq. (10) against the candidate ToA offset c (τ − τ₀), for several windows L.

    For a TDL-D (LoS) and a TDL-C (NLoS) link, with the link's sampled CIR power as grey stems.  A window of L taps
    sums the CIR power over [τ, τ + (L − 1) T_s], so where one tap holds the energy the cost is flat for (L − 1) T_s
    before the first path and falls off a cliff after it.

    Parameters
    ----------
    payload : dict
        The payload of ``studies.plateau_payload``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    d, c = payload["data"], payload["config"]
    x = np.asarray(d["offset_m"])
    titles = {"TDL-D": "TDL-D (LoS, K = {:g} dB)".format(c["k_factor_db"]), "TDL-C": "TDL-C (NLoS)"}
    with style():
        fig = Figure(figsize=(7.4, 4.2), layout="constrained")
        axes = fig.subplots(1, 2, sharey=True)
        for ax, name in zip(axes, ("TDL-D", "TDL-C")):
            p = d[name]
            keep = np.asarray(p["cir_offset_m"]) <= x.max()
            ax.vlines(np.asarray(p["cir_offset_m"])[keep], 0, np.asarray(p["cir_power"])[keep], color="0.6", lw=2.5,
                      label="sampled CIR power |h[n]|²")
            for n, col in zip(c["taps"], COLORS):
                plateau = (n - 1) * c["sample_m"]
                lab = f"L = {n}" + (f" (plateau (L − 1)cTₛ = {plateau:.1f} m)" if n > 1 else "")
                ax.plot(x, d[name]["cost"][str(n)], color=col, lw=1.4, label=lab)
            ax.axvline(0.0, color="k", lw=0.8, ls=":")
            ax.set_xlim(x.min(), x.max())
            ax.set_ylim(0, 1.05)
            ax.set_xlabel("candidate ToA offset c(τ − τ₀) (m)")
            ax.set_title(titles[name], fontsize=9)
        axes[0].set_ylabel("cost of one link / its maximum")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize=9, frameon=False)
    return fig
