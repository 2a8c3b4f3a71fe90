"""Command line: ``dpe5g run`` (a Monte Carlo DPE study on your deployment), ``dpe5g figures`` (the figure build
script), ``dpe5g warm`` (fill the Monte Carlo cache), ``dpe5g reproduce`` and ``dpe5g verify`` (rewrite the results
store from today's code, or check a sample of it), ``dpe5g profile`` (print a scaled TDL table), ``dpe5g deployment``
(check and summarise a deployment file) and ``dpe5g scene`` (export the 3-D scene as HTML).  ``run``, ``warm`` and
``reproduce`` take ``--scheduler`` / ``--workers`` to run on a Dask cluster (``cluster``).

Bad input, including a file that cannot be read or written, ends with one line on stderr that names the parameter
and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal as os_signal  # (the name signal is dpe5g.signal)
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from ._io import output_file, writable_dir

#: the committed figure baselines (``figures/`` of the repository); ``dpe5g figures`` writes here only with
#: ``--update-baselines``
BASELINE_DIR = Path(__file__).resolve().parent.parent / "figures"

#: library parameter → the ``dpe5g run`` option that sets it, so an error raised by the library names the option
RUN_OPTIONS = {"n_trials": "--trials", "snr_db": "--snr", "snrs_db": "--snr", "m_values": "--m", "n_taps": "--taps",
               "delay_spread_s": "--delay-spread", "centring": "--centring", "prior_scale_m": "--prior-sigma",
               "seed": "--seed", "deployment file": "--deployment", "prs_reuse": "--reuse"}


class UsageError(Exception):
    """A command-line syntax error (argparse's), reported as one line: ``<prog>: error: <message>``."""

    def __init__(self, prog: str, message: str):
        super().__init__(message)
        self.prog = prog


class Parser(argparse.ArgumentParser):
    """argparse's parser with its errors raised as ``UsageError`` (``main`` prints them on one line, exit 2)
    instead of a usage block."""

    def error(self, message):
        raise UsageError(self.prog, f"{message} (see {self.prog} --help)")


# ---- shared checks --------------------------------------------------------------------------------------------------

def _in_baselines(folder: Path) -> bool:
    """Whether ``folder`` (resolved) is the committed baselines folder or inside it."""
    return folder.resolve().is_relative_to(BASELINE_DIR.resolve())


def _numbers_as_values(argv: list[str]) -> list[str]:
    """argparse takes ``-65e-9`` or ``-inf`` for an option (only ``-12`` and ``-1.5`` look like numbers to it), so
    ``--delay-spread -65e-9`` would fail with a misleading "expected one argument".  Every token that is a negative
    number gets a leading space, which makes argparse read it as a value; ``float`` and ``int`` ignore the space."""
    out = []
    for tok in argv:
        if tok.startswith("-") and len(tok) > 1 and not re.fullmatch(r"-\d+|-\d*\.\d+", tok):
            try:
                float(tok)
                tok = " " + tok
            except ValueError:
                pass
        out.append(tok)
    return out


# ---- dpe5g run ------------------------------------------------------------------------------------------------------

def _with_option(err: ValueError, options: dict[str, str]) -> ValueError:
    """``err`` with the command-line option of the library parameter its message starts with put in front."""
    msg = str(err)
    for name, option in options.items():
        if re.match(rf"{re.escape(name)}\b", msg):
            return ValueError(f"{option}: {msg}")
    return err


def run_experiment(args):
    """The ``experiment.Experiment`` of ``dpe5g run``'s arguments: the paper's Fig. 9 set-up (``dpe5g.paper``) with
    the user's deployment, SNRs (dB), M values, trials, receiver window L (taps), delay spread (s), centring, prior
    σ (m) and seed.  Centring "truth" uses the paper's coarse-to-fine grid (``search_config.SearchConfig()``), "prior"
    and "otdoa" the honest certified search (``paper.honest_search()``), as the figures do.  When everything equals one
    of the paper's experiments, that experiment (and its cache) is used."""
    from dataclasses import replace

    from . import paper, search_config, signal
    from .deployment import builtin
    from .experiment import Experiment

    dep = args.deployment if builtin(args.deployment) else str(Path(args.deployment).resolve())
    if args.reuse and args.centring == "truth":
        raise ValueError(f"--reuse {args.reuse} needs the honest receiver's certified search: use --centring prior "
                         f"or --centring otdoa, not truth")
    if args.prior_sigma is not None and args.centring != "prior":
        raise ValueError(f"--prior-sigma applies to --centring prior only (got --centring {args.centring})")
    prior_sigma = paper.PRIOR_SIGMA_M if args.prior_sigma is None else args.prior_sigma
    if not (math.isfinite(prior_sigma) and 0 < prior_sigma <= 1000):
        raise ValueError(f"--prior-sigma must be in (0, 1000] m, got {prior_sigma!r} (for no prior error, use "
                         f"--centring truth)")
    try:
        for snr in args.snr:
            signal.check_snr_db(snr)  # one by one, so that the message shows the bad value
        search = search_config.SearchConfig(n_taps=args.taps) if args.centring == "truth" else replace(paper.honest_search(),
                                                                                             n_taps=args.taps)
        kw = dict(n_trials=args.trials, seed=args.seed, snrs_db=tuple(args.snr), m_values=tuple(args.m),
                  delay_spread_s=args.delay_spread, centring=args.centring, search=search, deployment=dep)
        if args.centring != "truth":
            kw.update(prior_kind="gaussian", prior_scale_m=prior_sigma)
        if args.reuse:  # interference needs each BS's power: --snr is then the nearest link's SNR
            kw.update(prs_reuse=args.reuse, snr_mode="nearest")
        e = Experiment.build(name="run", otdoa=args.centring == "otdoa", **kw)
        e.load_deployment()  # the file, and M against its BS count
    except ValueError as err:
        raise _with_option(err, RUN_OPTIONS) from None
    for known in (paper.fig9_honest(args.trials), paper.fig9_truth(args.trials),
                  paper.fig9_power(args.trials, args.reuse)):
        if e.replace(name=known.run.name) == known:
            return known
    return e


def _run(args) -> int:
    from . import engine, report
    from ._io import atomic_target

    e = run_experiment(args)
    out = output_file("--out", args.out, (".csv", ".json"), force=args.force)
    with _cluster(args) as client:
        res = engine.run(e, progress=True, client=client)
    try:  # an existing file is never left half-overwritten; without --force, never replaced
        with atomic_target(out, exclusive=not args.force) as tmp:
            (res.write_csv if out.suffix.lower() == ".csv" else res.write_json)(tmp)
    except FileExistsError:
        raise ValueError(f"--out {args.out}: another run wrote it meanwhile; the results of this one are in the "
                         f"cache: rerun with another --out, or --force to overwrite it") from None
    if threading.current_thread() is threading.main_thread():  # written: Ctrl-C now would only cut the summary
        os_signal.signal(os_signal.SIGINT, os_signal.SIG_IGN)
    n_rows = e.run.n_trials * len(e.links.snrs_db) * len(e.receiver.m_values)
    print(report.run_summary(res))
    print(f"wrote {out} ({n_rows} rows: one per trial, SNR and M)")
    return 0


# ---- dpe5g figures --------------------------------------------------------------------------------------------------

def _figures(args) -> int:
    from . import _checks, figures

    ids = args.only or list(figures.REGISTRY)
    for fig_id in ids:
        figures.get(fig_id)  # validate every id before spending time
    if args.trials is not None:
        _checks.integer("--trials", args.trials, 1, 10_000_000)
        if args.update_baselines:
            raise ValueError(f"--trials {args.trials} cannot be used with --update-baselines: the committed "
                             f"baselines use the paper's trial counts (dpe5g.paper); write elsewhere with --out DIR")
        if not any(figures.takes_trials(f) for f in ids):
            raise ValueError(f"--trials applies to the Monte Carlo figures "
                             f"({', '.join(f for f in figures.REGISTRY if figures.takes_trials(f))}), none selected")
    if args.update_baselines:
        if args.out is not None:
            raise ValueError(f"--out {args.out} cannot be used with --update-baselines, which writes the committed "
                             f"baselines in {BASELINE_DIR}")
        if not BASELINE_DIR.is_dir():
            raise ValueError(f"--update-baselines: no committed baselines folder {BASELINE_DIR} (it needs the "
                             f"repository checkout, an editable install)")
        out = BASELINE_DIR
    else:
        if args.out is None:
            raise ValueError("--out DIR is required: the committed baselines (figures/) are written only with "
                             "--update-baselines")
        out = Path(args.out)
        if _in_baselines(out):
            raise ValueError(f"--out {args.out} is in the committed baselines folder {BASELINE_DIR}; give another "
                             f"folder, or --update-baselines (without --out) to regenerate the baselines")
    writable_dir("--out", out)
    for fig_id in ids:
        t0 = time.perf_counter()
        trials = args.trials if args.trials is not None and figures.takes_trials(fig_id) else None
        png, js = figures.write(fig_id, out, progress=True, trials=trials)
        print(f"{fig_id}: {png} {js} ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


# ---- dpe5g warm ------------------------------------------------------------------------------------------------------

def _warm(args) -> int:
    from . import engine, verify

    exps = verify.store_experiments()
    order = exps if args.forward else exps[::-1]
    t0 = time.perf_counter()
    with _cluster(args) as client:
        for i, e in enumerate(order, 1):
            t = time.perf_counter()
            engine.run(e, progress=args.progress, reverse=not args.forward, client=client)
            print(f"[{i}/{len(order)}] {e.run.name}: {e.run.n_trials} trials ({time.perf_counter() - t:.1f} s)",
                  flush=True)
    print(f"warm: {len(order)} experiments in the cache ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


# ---- dpe5g reproduce, verify -----------------------------------------------------------------------------------------

def _reproduce(args) -> int:
    from . import store, verify

    if store.store_root() is None:
        raise ValueError("DPE5G_STORE is 'off': reproduce rewrites the results store; unset it or name a folder")
    writable_dir("DPE5G_STORE", store.store_root())
    with _cluster(args) as client:
        found = verify.reproduce(progress=args.progress, client=client)
    print(f"reproduce: {len(found)} stored (trial, field) values differed from today's code and were rewritten"
          if found else "reproduce: the store held what today's code computes", flush=True)
    return 0


def _verify(args) -> int:
    import random

    from . import _checks, verify

    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(2**31)
    _checks.integer("--seed", seed, 0, 2**31 - 1)
    families = verify.SAMPLE_FAMILIES if args.families is None else args.families
    n_trials = _checks.integer("--trials", verify.SAMPLE_TRIALS if args.trials is None else args.trials, 1, 10_000)
    n = len(verify.store_experiments()) if args.all else _checks.integer("--families", families, 1, 10_000)
    print(f"verify: seed {seed} (dpe5g verify --seed {seed} repeats this sample)", flush=True)
    found, done = verify.verify_sample(seed, n, n_trials)
    for m in found:
        print(m, file=sys.stderr)
    total = sum(len(t) for _, t in done)
    print(f"verify: {total} trials of {len(done)} experiments recomputed, {len(found)} mismatches", flush=True)
    return 1 if found else 0


@contextmanager
def _cluster(args):
    """The Dask client of --scheduler / DPE5G_SCHEDULER / --workers (``cluster.connect``), closed on exit; None
    (this process) without them."""
    from . import cluster

    client = cluster.connect(args.scheduler, args.workers)
    try:
        yield client
    finally:
        cluster.close(client)


def _add_cluster_options(p) -> None:
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the Monte Carlo chunks as tasks on the Dask scheduler at ADDRESS (tcp://host:8786; "
                        "default: DPE5G_SCHEDULER if set, else this process)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="start a Dask LocalCluster of N single-threaded worker processes on this machine")


# ---- dpe5g profile, deployment, scene -------------------------------------------------------------------------------

def _profile(args) -> int:
    from . import channel

    try:
        prof = channel.tdl_profile(args.name, args.delay_spread, args.k_factor_db)
    except ValueError as err:
        raise _with_option(err, {"delay_spread_s": "--delay-spread", "k_factor_db": "--k-factor-db"}) from None
    print(f"{prof.name} ({prof.table}) scaled to DS = {prof.delay_spread_s * 1e9:g} ns, K = {prof.k_factor_db}")
    print(f"{'tap':>3} {'delay (ns)':>11} {'power (dB)':>11} {'kind':>9}")
    for i, (d, p, los) in enumerate(zip(prof.delays_s, prof.powers_db, prof.los)):
        print(f"{i:3d} {d * 1e9:11.3f} {p:11.2f} {'LoS' if los else 'Rayleigh':>9}")
    print(f"RMS delay spread of the scaled profile: {channel.rms_delay_spread(prof.delays_s, prof.powers) * 1e9:.3f} ns")
    return 0


def _deployment(args) -> int:
    import numpy as np

    from . import deployment

    dep = deployment.named(args.path)
    x0, y0, x1, y1 = dep.region
    nearest = deployment.nearest_neighbours(dep.bs_xyz[:, :2])[0]
    print(f"{dep.name}: {dep.n_bs} BSs, region {x1 - x0:.1f} m x {y1 - y0:.1f} m = {dep.area_m2:,.0f} m2, "
          f"{dep.n_bs / dep.area_m2 * 1e6:.1f} BSs per km2, nearest-neighbour spacing {np.median(nearest):.1f} m "
          f"(median), {len(dep.buildings)} buildings, UE height {dep.ue_height_m:g} m"
          + ("" if dep.ue_region is None else
             ", UE drawn in {:.1f} m x {:.1f} m".format(dep.ue_region[2] - dep.ue_region[0],
                                                       dep.ue_region[3] - dep.ue_region[1])))
    return 0


def _scene(args) -> int:
    from . import figures, scene3d

    out = output_file("--out", args.out, (".html", ".htm"), force=args.force)
    try:
        path = scene3d.export(figures.compute("fig07_deployment_map"), figures.compute("fig08_urban_correlogram"), out,
                              exclusive=not args.force)
    except FileExistsError:
        raise ValueError(f"--out {args.out}: another process wrote it meanwhile; pass --force to overwrite "
                         f"it") from None
    print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``dpe5g`` parser: one subcommand each for run, figures, warm, profile, deployment and scene."""
    p = Parser(prog="dpe5g", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    _add_run(sub)
    _add_other_commands(sub)
    return p


def _add_run(sub) -> None:
    """``dpe5g run``: its options, with the paper's Fig. 9 set-up as defaults."""
    from . import paper, search_config
    from .experiment import Experiment

    paper_e = Experiment()
    r = sub.add_parser(
        "run", help="run a Monte Carlo DPE study (RMSE vs SNR and M) and write its per-trial results",
        description="Run a Monte Carlo DPE study on a deployment: per trial a UE in the region, its M nearest BSs, "
                    "LoS from eq. (11), TDL-D / TDL-C, a clock bias, then a DPE fix per SNR and M (defaults: Fig. 9 "
                    "with the honest receiver).  Results are cached (.cache/montecarlo, or DPE5G_CACHE): a rerun, or "
                    "an interrupted run restarted, computes only the missing trials.  Prints an RMSE table.",
        epilog=f"Cost: a truth-centred fix is a few ms per (SNR, M); an honest one (prior, otdoa) tens of ms "
               f"(certified search), plus a compile of 10-60 s per run.  The paper's Fig. 9 uses "
               f"{paper.FIG9_HONEST_TRIALS} (honest) and {paper.FIG9_TRUTH_TRIALS} (truth) trials; with exactly "
               f"those settings the figure's cached results are reused.")
    r.add_argument("--trials", type=int, required=True, metavar="N",
                   help="Monte Carlo trials (required; trial t's draws depend only on --seed and t)")
    r.add_argument("--out", required=True, metavar="FILE",
                   help="results file, .csv (tidy table, one row per trial, SNR and M) or .json (the same rows and "
                        "the experiment's config); an existing file is kept unless --force")
    r.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    r.add_argument("--deployment", default="tst", metavar="FILE",
                   help="deployment file, JSON or CSV (see `dpe5g deployment`), or a packaged one: 'tst' (the "
                        "default; our Tsim Sha Tsui-like layout), 'ring' or 'ring-wide' (the DPE chapter's rings)")
    r.add_argument("--snr", type=float, nargs="+", default=list(paper_e.links.snrs_db), metavar="DB",
                   help=f"per-sample SNRs in dB, in [-50, 100] (default: the paper's "
                        f"{' '.join(f'{s:g}' for s in paper_e.links.snrs_db)})")
    r.add_argument("--m", type=int, nargs="+", default=list(paper_e.receiver.m_values), metavar="M",
                   help=f"numbers of nearest BSs used by the DPE, increasing, each >= 3 (x, y and the clock bias "
                        f"are unknown) and <= the deployment's BS count (default: "
                        f"{' '.join(map(str, paper_e.receiver.m_values))})")
    r.add_argument("--taps", type=int, default=search_config.DEFAULT_TAPS, metavar="L",
                   help=f"receiver window L in taps, 1 to the FFT size (default: {search_config.DEFAULT_TAPS}, chosen in "
                        f"the Fig. 9 chapter)")
    r.add_argument("--delay-spread", type=float, default=paper_e.scenario.delay_spread_s, metavar="S",
                   help=f"RMS delay spread of the TDL channels in SECONDS (default: "
                        f"{paper_e.scenario.delay_spread_s * 1e9:g}e-9, TR 38.901 UMi short)")
    r.add_argument("--centring", default="prior", metavar="{truth,prior,otdoa}",
                   help="where the search window is centred: 'prior' (default; the honest receiver of Fig. 9: "
                        "truth + a Gaussian error of --prior-sigma per axis, certified search), 'otdoa' (on the "
                        "trial's OTDoA first-path fix, certified search; the OTDoA errors are written too) or "
                        "'truth' (the paper's own set-up, a labelled comparison: grid centred on the true position "
                        "and clock bias)")
    r.add_argument("--prior-sigma", type=float, default=None, metavar="M",
                   help=f"σ per axis of the prior's error in metres, in (0, 1000], centring 'prior' only (default: "
                        f"{paper.PRIOR_SIGMA_M:g})")
    r.add_argument("--seed", type=int, default=paper.URBAN_SEED, help=f"seed (default: {paper.URBAN_SEED}, Fig. 9's)")
    r.add_argument("--reuse", type=int, default=0, metavar="R",
                   help="PRS frequency reuse factor: 0 (default) the paper's model, every BS's PRS on all bins and "
                        "received alone; 2, 4, 6 or 12 (Table I: 6) the TS 38.211 comb R over R symbols with every BS "
                        "of the deployment transmitting and co-channel interference; --snr is then the SNR of the "
                        "nearest link, every other BS at its power from the path loss (the Fig. 9 chapter)")
    _add_cluster_options(r)
    r.set_defaults(func=_run)


def _add_other_commands(sub) -> None:
    """``dpe5g figures``, ``warm``, ``profile``, ``deployment`` and ``scene``."""
    f = sub.add_parser("figures", help="regenerate figures: <out>/<id>.png and <out>/data/<id>.json",
                       description="Regenerate figures into --out DIR, or the committed baselines (figures/ of the "
                                   "repository) with --update-baselines; nothing is written into figures/ otherwise.")
    f.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (required unless --update-baselines; must not be in figures/)")
    f.add_argument("--update-baselines", action="store_true",
                   help=f"write the committed baselines ({BASELINE_DIR}) with the paper's trial counts (make figures)")
    f.add_argument("--only", nargs="+", metavar="ID", help="figure ids (default: all registered)")
    f.add_argument("--trials", type=int, default=None, metavar="N",
                   help="Monte Carlo trials per experiment of Figs. 9-10 (default: the committed figures' counts); "
                        "not with --update-baselines")
    f.set_defaults(func=_figures)

    w = sub.add_parser("warm", help="fill the Monte Carlo cache with every experiment the book runs",
                       description="Run (or load) every experiment of dpe5g.verify.store_experiments into the cache, "
                                   "last first, so that a book build running at the same time meets it in the middle. "
                                   "The results are the book's own to the bit (trial t depends on the seed and t).")
    w.add_argument("--forward", action="store_true", help="run in the book's order instead")
    w.add_argument("--progress", action="store_true", help="a progress bar per experiment on stderr")
    _add_cluster_options(w)
    w.set_defaults(func=_warm)

    rp = sub.add_parser("reproduce", help="recompute every experiment of the results store and rewrite it",
                        description="Recompute every Monte Carlo experiment the results store (figures/trials) holds "
                                    "from its seeds, report every stored trial that differs from what today's code "
                                    "computes, and rewrite the store.  `make reproduce` runs it, then regenerates "
                                    "the figure baselines.  Run it after a change that `make test`'s verification "
                                    "fails on.")
    rp.add_argument("--progress", action="store_true", help="a progress bar per experiment on stderr")
    _add_cluster_options(rp)
    rp.set_defaults(func=_reproduce)

    v = sub.add_parser("verify", help="recompute a random sample of stored trials and compare them with the store",
                       description="Recompute --trials random trials of every experiment in --families random "
                                   "families of the results store (experiments that share their compiled programs) "
                                   "and compare every stored field; exit 1 naming each mismatch.")
    v.add_argument("--seed", type=int, default=None, help="the sample's seed (default: a new one, printed)")
    v.add_argument("--families", type=int, default=None, metavar="N",
                   help="families to sample (default: make test's sample, dpe5g.verify.SAMPLE_FAMILIES)")
    v.add_argument("--trials", type=int, default=None, metavar="N",
                   help="trials per experiment (default: dpe5g.verify.SAMPLE_TRIALS)")
    v.add_argument("--all", action="store_true", help="every family (--trials of each stored experiment)")
    v.set_defaults(func=_verify)

    t = sub.add_parser("profile", help="print a TR 38.901 TDL profile scaled to a delay spread")
    t.add_argument("name", help="A, B, C, D or E")
    t.add_argument("--delay-spread", type=float, default=65e-9, metavar="S",
                   help="desired RMS delay spread in SECONDS (65e-9)")
    t.add_argument("--k-factor-db", type=float, default=None, help="K-factor override for D/E, dB")
    t.set_defaults(func=_profile)

    d = sub.add_parser("deployment", help="check a deployment file (JSON or CSV) and print a summary")
    d.add_argument("path", nargs="?", default="tst",
                   help="path, or a packaged deployment: 'tst' (default), 'ring', 'ring-wide'")
    d.set_defaults(func=_deployment)

    s = sub.add_parser("scene", help="export the meshcat 3-D scene of the urban example as a static HTML file")
    s.add_argument("--out", default="urban_scene.html", metavar="FILE.html",
                   help="output HTML file (default: urban_scene.html); an existing file is kept unless --force")
    s.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    s.set_defaults(func=_scene)


_one_line = lambda text: " ".join(str(text).split())  # noqa: E731  (a message on one line)


def _interrupted(prog: str):
    """Ctrl-C, at any moment of a command: the files being written are removed (every finished file is whole:
    ``_io.atomic_target``), one line, exit code 130 at once.  Not a KeyboardInterrupt: raised inside a callback
    (JAX's garbage collection hook) or while threads finish, it was swallowed or ended the process unexplained."""
    from ._io import remove_in_flight

    remove_in_flight()
    sys.stdout.flush()
    bars = getattr(getattr(sys.modules.get("tqdm"), "tqdm", None), "_instances", None)  # a progress bar is drawn:
    sys.stderr.write("\n" if bars else "")  # end its line first
    sys.stderr.write(f"{prog}: interrupted (finished Monte Carlo chunks are cached; the same command resumes)\n")
    sys.stderr.flush()
    os._exit(130)


def main(argv=None) -> int:
    """Run the command line; returns the exit code (0, or 2 after one line on stderr for bad input)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    prog = "dpe5g"
    on_main = threading.current_thread() is threading.main_thread()
    previous = os_signal.signal(os_signal.SIGINT, lambda signum, frame: _interrupted(prog)) if on_main else None
    try:
        args = parser.parse_args(_numbers_as_values(argv))
        prog = f"dpe5g {args.command}"
        return args.func(args)
    except UsageError as e:
        print(f"{e.prog}: error: {_one_line(e)}", file=sys.stderr)
    except ValueError as e:
        print(f"{prog}: error: {_one_line(e)}", file=sys.stderr)
    except OSError as e:
        where = f": {e.filename}" if e.filename else ""
        print(f"{prog}: error: {_one_line(e.strerror or e)}{where}", file=sys.stderr)
    except KeyboardInterrupt:  # (called from another thread, where the handler above cannot be set)
        print(f"{prog}: interrupted (finished Monte Carlo chunks are cached; the same command resumes)",
              file=sys.stderr)
        return 130
    finally:  # give a caller in this process its handler back; the command line's start-up handler stays replaced
        if on_main and getattr(previous, "__module__", None) != "dpe5g":
            os_signal.signal(os_signal.SIGINT, previous)
    return 2


def entry() -> None:
    """The ``dpe5g`` script and ``python -m dpe5g``: ``main``, then exit at once (output flushed, files closed),
    skipping the interpreter's shutdown, where a Ctrl-C would end the process with no word."""
    code = main()
    sys.stdout.flush(), sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
