"""Command line: ``dpe5g figures`` (the figure build script), ``dpe5g profile`` (print a scaled TDL table),
``dpe5g deployment`` (check and summarise a deployment file) and ``dpe5g scene`` (export the 3-D scene as HTML).

Bad input ends with one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
import time


def _figures(args) -> int:
    from pathlib import Path

    from . import _checks, figures

    ids = args.only or list(figures.REGISTRY)
    for fig_id in ids:
        figures.get(fig_id)  # validate every id before spending time
    if args.trials is not None:
        _checks.integer("--trials", args.trials, 1, 10_000_000)
        mc = [f for f in ids if figures.takes_trials(f)]
        if not mc:
            raise ValueError(f"--trials applies to the Monte Carlo figures "
                             f"({', '.join(f for f in figures.REGISTRY if figures.takes_trials(f))}), none selected")
        if Path(args.out).resolve() == (Path(figures.__file__).resolve().parent.parent / "figures"):
            raise ValueError(f"--out {args.out} holds the committed baselines; figures with --trials {args.trials} "
                             f"are not those, so give --out another folder")
    for fig_id in ids:
        t0 = time.perf_counter()
        trials = args.trials if args.trials is not None and figures.takes_trials(fig_id) else None
        png, js = figures.write(fig_id, args.out, progress=True, trials=trials)
        print(f"{fig_id}: {png} {js} ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


def _profile(args) -> int:
    from . import channel

    prof = channel.tdl_profile(args.name, args.delay_spread, args.k_factor_db)
    print(f"{prof.name} ({prof.table}) scaled to DS = {prof.delay_spread_s * 1e9:g} ns, K = {prof.k_factor_db}")
    print(f"{'tap':>3} {'delay (ns)':>11} {'power (dB)':>11} {'kind':>9}")
    for i, (d, p, los) in enumerate(zip(prof.delays_s, prof.powers_db, prof.los)):
        print(f"{i:3d} {d * 1e9:11.3f} {p:11.2f} {'LoS' if los else 'Rayleigh':>9}")
    print(f"RMS delay spread of the scaled profile: {channel.rms_delay_spread(prof.delays_s, prof.powers) * 1e9:.3f} ns")
    return 0


def _deployment(args) -> int:
    import numpy as np

    from . import deployment

    dep = deployment.tst() if args.path == "tst" else deployment.load_deployment(args.path)
    x0, y0, x1, y1 = dep.region
    d = np.linalg.norm(dep.bs_xyz[:, None, :2] - dep.bs_xyz[None, :, :2], axis=-1) + np.eye(dep.n_bs) * 1e9
    print(f"{dep.name}: {dep.n_bs} BSs, region {x1 - x0:.1f} m x {y1 - y0:.1f} m = {dep.area_m2:,.0f} m2, "
          f"{dep.n_bs / dep.area_m2 * 1e6:.1f} BSs per km2, nearest-neighbour spacing {np.median(d.min(1)):.1f} m "
          f"(median), {len(dep.buildings)} buildings, UE height {dep.ue_height_m:g} m")
    return 0


def _scene(args) -> int:
    from . import figures, scene3d

    path = scene3d.export(figures.compute("fig07_deployment_map"), figures.compute("fig08_urban_correlogram"),
                          args.out)
    print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dpe5g", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("figures", help="regenerate figures: <out>/<id>.png and <out>/data/<id>.json")
    f.add_argument("--out", default="figures", help="output folder (default: figures)")
    f.add_argument("--only", nargs="+", metavar="ID", help="figure ids (default: all registered)")
    f.add_argument("--trials", type=int, default=None, metavar="N",
                   help="Monte Carlo trials per experiment of Figs. 9-10 (default: the committed figures' counts)")
    f.set_defaults(func=_figures)
    t = sub.add_parser("profile", help="print a TR 38.901 TDL profile scaled to a delay spread")
    t.add_argument("name", help="A, B, C, D or E")
    t.add_argument("--delay-spread", type=float, default=65e-9, help="desired RMS delay spread in SECONDS (65e-9)")
    t.add_argument("--k-factor-db", type=float, default=None, help="K-factor override for D/E, dB")
    t.set_defaults(func=_profile)
    d = sub.add_parser("deployment", help="check a deployment file (JSON or CSV) and print a summary")
    d.add_argument("path", nargs="?", default="tst", help="path, or 'tst' for the packaged layout (default)")
    d.set_defaults(func=_deployment)
    s = sub.add_parser("scene", help="export the meshcat 3-D scene of the urban example as a static HTML file")
    s.add_argument("--out", default="urban_scene.html", help="output HTML file (default: urban_scene.html)")
    s.set_defaults(func=_scene)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ValueError as e:
        print(f"dpe5g: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
