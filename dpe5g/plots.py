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
from matplotlib.figure import Figure

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
    """Fig. 6: eq. (8) normalized to its maximum over (x, y), (a) as a map, (b) cuts through the peak."""
    d = payload["data"]
    cfg = payload["config"]
    x, y = np.asarray(d["x_m"]), np.asarray(d["y_m"])
    c = np.asarray(d["cost_norm"])
    ue = cfg["ue_xyz"]
    with style():
        fig = Figure(figsize=(8.0, 3.4), layout="constrained")
        ax_a, ax_b = fig.subplots(1, 2)
        im = ax_a.pcolormesh(x, y, c, shading="nearest", cmap="viridis", vmin=0, vmax=1)
        fig.colorbar(im, ax=ax_a, label="normalized cost")
        ax_a.plot(ue[0], ue[1], "r+", markersize=12, mew=2, label="true position")
        ax_a.plot(*d["peak_xy"], "wx", markersize=8, mew=1.5, label="grid maximum")
        ax_a.set_xlabel("x (m)")
        ax_a.set_ylabel("y (m)")
        ax_a.set_aspect("equal")
        ax_a.legend(fontsize=7, loc="lower left")
        ax_a.set_title(f"(a) eq. (8), {cfg['n_bs']} BSs, L = {cfg['n_taps_receiver']} taps")
        iy = int(np.argmin(np.abs(y - ue[1])))
        ix = int(np.argmin(np.abs(x - ue[0])))
        ax_b.plot(x, c[iy, :], label="cut along x at true y")
        ax_b.plot(y, c[:, ix], "--", label="cut along y at true x")
        ax_b.axvline(0.0, color="r", lw=0.8)
        ax_b.set_xlabel("offset from true position (m)")
        ax_b.set_ylabel("normalized cost")
        ax_b.set_title("(b) cuts through the true position")
        ax_b.legend(fontsize=7)
    return fig
