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
