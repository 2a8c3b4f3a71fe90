"""The ``dpe5g`` command line's parser: its subcommands and options, with their help (``build_parser``); ``cli``
runs them.  argparse's syntax errors are raised as ``UsageError`` so that ``cli.main`` prints them on one line."""

from __future__ import annotations

import argparse
import re
import textwrap
from pathlib import Path

from ..common.locations import BASELINE_DIR  # noqa: F401  (cli reads it from here too)

#: what ``dpe5g --help`` says first
DESCRIPTION = (
    "The command line of dpe5g, the companion of the paper '5G Direct Position Estimation for Precise Localization "
    "in Dense Urban Area': run (a Monte Carlo DPE study on your deployment), figures (the figure build script), warm "
    "(fill the Monte Carlo cache), reproduce and verify (rewrite the results store from today's code, or check a "
    "sample of it), profile (print a scaled TDL table), deployment (check and summarise a deployment file) and "
    "scene (export the 3-D scene as HTML); run, warm, reproduce and trace take --scheduler or --workers to run on a Dask "
    "cluster.  Bad input ends with one line naming the parameter and exit code 2; a failure that is not the "
    "input's (a damaged results store, a Dask cluster that lost work or runs other code) with one line and exit "
    "code 1; Ctrl-C and SIGTERM with one line and exit codes 130 and 143.")



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


def numbers_as_values(argv: list[str]) -> list[str]:
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


def add_progress_options(p, what: str) -> None:
    """``--progress`` and ``--quiet``: ``what`` (a progress bar, the steps) is shown on stderr by default when stderr
    is a terminal (``main.show_progress``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--progress", action="store_true", default=None,
                   help=f"show {what} on stderr even when it is not a terminal (shown on a terminal by default)")
    g.add_argument("--quiet", action="store_true", help=f"do not show {what}")


def add_cluster_options(p, what: str = "the Monte Carlo chunks") -> None:
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help=f"run {what} as tasks on the Dask scheduler at ADDRESS (tcp://host:8786; "
                        "default: DPE5G_SCHEDULER if set, else this process)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="start a Dask LocalCluster of N single-threaded worker processes on this machine")


def build_parser() -> argparse.ArgumentParser:
    """The ``dpe5g`` parser: one subcommand each for run, figures, warm, reproduce, trace, verify, profile,
    deployment and scene, described by ``DESCRIPTION``."""
    p = Parser(prog="dpe5g", description=DESCRIPTION)
    sub = p.add_subparsers(dest="command", required=True)
    add_run(sub)
    add_other_commands(sub)
    return p


def add_run(sub) -> None:
    """``dpe5g run``: its options, with the paper's Fig. 9 set-up as defaults."""
    from ..receivers import search_config
    from ..studies import paper
    from ..simulation.experiment import Experiment

    paper_e = Experiment()
    r = sub.add_parser(
        "run", help="run a Monte Carlo DPE study (RMSE vs SNR and M) and write its per-trial results",
        description="Run a Monte Carlo DPE study on a deployment: per trial a UE in the region, its M nearest BSs, "
                    "LoS from eq. (11), TDL-D / TDL-C, a clock bias, then a DPE fix per SNR and M (defaults: Fig. 9 "
                    "with the honest receiver).  Results are cached (.cache/montecarlo, or DPE5G_CACHE): a rerun, or "
                    "an interrupted run restarted, computes only the missing trials.  Prints an RMSE table.",
        epilog=f"Cost: a truth-centred fix is a few ms per (SNR, M); an honest one (prior, otdoa) tens of ms "
               f"(certified search), plus a compile of 10-60 s per run.  The book's Fig. 9 uses "
               f"{paper.FIG9_HONEST_TRIALS} (honest) and {paper.FIG9_TRUTH_TRIALS} (truth) trials (the paper "
               f"{paper.URBAN_TRIALS}); with exactly those settings the figure's stored results are reused.")
    r.add_argument("--trials", type=int, required=True, metavar="N",
                   help="Monte Carlo trials (required; trial t's draws depend only on --seed and t)")
    r.add_argument("--out", required=True, metavar="FILE",
                   help="results file, .csv: a header line, then one row per trial, SNR and M, every cell one value "
                        "(any CSV reader reads it as it is); beside it, FILE with .json in place of .csv, what "
                        "produced it (the experiment's settings, the deployment, the code's commit) and what each "
                        "column means; existing files are kept unless --force")
    r.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    r.add_argument("--deployment", default=None, metavar="FILE",
                   help="deployment file, JSON or CSV (see `dpe5g deployment`), or a packaged one: 'tst' (the "
                        "default; our Tsim Sha Tsui-like layout), 'ring' or 'ring-wide' (the DPE chapter's rings)")
    r.add_argument("--channel", default="tdl", metavar="{tdl,traced}",
                   help="'tdl' (default): TR 38.901's TDL channels, LoS from eq. (11); 'traced': the ray-traced "
                        "paths of --city, LoS from its geometry (the city chapter, chapter 10)")
    r.add_argument("--city", default=None, metavar="DIR|NAME",
                   help="with --channel traced: the folder `dpe5g trace --out DIR` wrote (one city), a city's "
                        "deployment file in it (DIR/cities/NAME_deployment.json), or a city of the results store "
                        "by name ('munich', the book's)")
    r.add_argument("--snr-mode", default="fixed", metavar="{fixed,link-budget}",
                   help="'fixed' (default; Fig. 9): every link at each SNR of --snr, whatever the BSs' powers; "
                        "'link-budget' (Fig. 10): each link's SNR from its BS's power_dbm, the TR 38.901 UMi path "
                        "loss and the receiver's noise (Table I), one SNR per link and no --snr")
    r.add_argument("--snr", type=float, nargs="+", default=None, metavar="DB",
                   help=f"per-sample SNRs in dB, in [-50, 100] (default: the paper's "
                        f"{' '.join(f'{s:g}' for s in paper_e.links.snrs_db)}); with --reuse, the nearest link's")
    r.add_argument("--m", type=int, nargs="+", default=None, metavar="M",
                   help=f"numbers of nearest BSs used by the DPE, increasing, each >= 3 (x, y and the clock bias "
                        f"are unknown) and <= the deployment's BS count (default: the paper's "
                        f"{' '.join(map(str, paper_e.receiver.m_values))} that fit the deployment, and its BS count "
                        f"if below {max(paper_e.receiver.m_values)}; with --snr-mode link-budget, Fig. 10's 4)")
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
    add_nlos_options(r)
    add_progress_options(r, "a progress bar over the trials")
    add_cluster_options(r)
    r


def add_nlos_options(r) -> None:
    """``dpe5g run``'s options of the LoS model, the NLoS excess delay and the NLoS-aware receivers (the book's
    chapter on the paper's central claim under an NLoS bias, ``chapters/09_nlos_bias.md``)."""
    from ..phy.propagation import TR38901_EXCESS_DELAY
    from ..simulation.experiment import LOS_MODES

    rows = ", ".join(f"{k} (median {row.median_s * 1e9:.0f} ns, σ {row.sigma_lg:g} decades)"
                     for k, row in TR38901_EXCESS_DELAY.items())
    r.add_argument("--los-mode", default="pr_los", metavar="{" + ",".join(LOS_MODES) + "}",
                   help="which links are LoS: 'pr_los' (default; each with eq. (11)'s probability, the paper's), "
                        "'two_of_four' (Fig. 10's case: 2 of the 4 nearest at random; --m 4), 'nearest_two_los' (the "
                        "2 nearest of 4; --m 4), 'all_los', 'all_nlos', 'free_space' (one LoS path, no multipath); "
                        "chapters 4 (eq. (11)) and 6 (Fig. 10)")
    r.add_argument("--nlos-excess", default="none", metavar="{none," + ",".join(TR38901_EXCESS_DELAY) + "}",
                   help="NLoS excess delay (not in the paper's model; chapter 9): 'none' (default) or a row of TR "
                        f"38.901 Table 7.6.9-1, every path of an NLoS link late by a log-normal delay: {rows}")
    r.add_argument("--dpe-nlos", action="store_true",
                   help="the NLoS-aware DPE (chapter 9, eq. (D1)): each link's excess delay integrated out under the "
                        "--nlos-excess law (UMi's where none is given) and eq. (11)'s LoS probability, its clock "
                        "window widened by that law; not with --centring truth")
    r.add_argument("--otdoa-nlos", action="store_true",
                   help="also the NLoS-aware OTDoA (chapter 9): each link's ToA weighted by its variance, a residual "
                        "test flags and excludes NLoS links; needs --centring otdoa")


def add_other_commands(sub) -> None:
    """``dpe5g figures`` and ``warm``, then the store's commands and the others."""
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
    add_progress_options(f, "a progress bar per Monte Carlo figure")
    f

    w = sub.add_parser("warm", help="fill the Monte Carlo cache with every experiment the book runs",
                       description="Run (or load) every experiment of dpe5g.studies.catalog.store_experiments into the cache, "
                                   "last first, so that a book build running at the same time meets it in the middle. "
                                   "The results are the book's own to the bit (trial t depends on the seed and t).")
    w.add_argument("--forward", action="store_true", help="run in the book's order instead")
    add_progress_options(w, "a progress bar per experiment")
    add_cluster_options(w)
    w
    add_store_commands(sub)
    add_info_commands(sub)


def add_store_commands(sub) -> None:
    """``dpe5g reproduce``, ``trace`` and ``verify``: the results store's commands."""
    rp = sub.add_parser("reproduce", help="recompute every experiment of the results store and rewrite it",
                        description="Recompute every Monte Carlo experiment the results store (figures/trials) holds "
                                    "from its seeds, report every stored trial that differs from what today's code "
                                    "computes, and rewrite the store.  `make reproduce` runs it, then regenerates "
                                    "the figure baselines.  Run it after a change that `make test`'s verification "
                                    "fails on, once that change is committed: each entry records the commit whose "
                                    "code computed it.")
    add_progress_options(rp, "a progress bar per experiment")
    rp.add_argument("--allow-dirty", action="store_true",
                    help="run although dpe5g/, environment.txt or pyproject.toml differ from the checkout's commit "
                         "(refused otherwise); every entry then records the commit and a digest of the changes")
    add_cluster_options(rp)
    rp

    tc = sub.add_parser("trace", help="ray-trace the city of the city chapter (Sionna RT) into the results store",
                        description="Place the BSs and UEs in Sionna RT's scene, trace every link (city_trace.CitySpec) "
                                    "and write the paths to the results store (figures/trials/cities) and the "
                                    "city's deployment beside them, unless they were traced with today's settings "
                                    "and tracing code; then the 3-D view (the buildings, one UE's traced paths), "
                                    "a subset of its UEs under each solver setting of "
                                    "city_sensitivity.VARIANTS and the denser networks of city_density that are not "
                                    "stored yet.  `make reproduce` runs it first (from scratch on 2 cores about 37 "
                                    "minutes for the city, 38 for the subsets and 47 for the denser networks); it "
                                    "needs Debian's libllvm19 on the CPU.")
    add_progress_options(tc, "a progress bar over the UEs")
    tc.add_argument("--force", action="store_true", help="trace again even if the stored city is current")
    add_cluster_options(tc, "the tracing chunks (batches of UEs; city.trace_chunks)")
    tc.add_argument("--chunk-batches", type=int, default=1, metavar="K",
                    help="solver batches of UEs per task on a cluster (default 1); the city is the same bits for any K")
    tc.add_argument("--backend", choices=("auto", "llvm", "cuda"), default="auto",
                    help="Dr.Jit's backend: 'llvm' (the CPU), 'cuda' (an NVIDIA GPU), 'auto' (default: CUDA where a "
                         "GPU answers, else the CPU, Sionna RT's own choice); a cached batch is reused on its own backend only")
    add_own_city_options(tc)
    tc

    v = sub.add_parser("verify", help="recompute a random sample of stored trials and compare them with the store",
                       description="Recompute --trials random trials of every experiment in --families random "
                                   "families of the results store (experiments that share their compiled programs) "
                                   "and compare every stored field; exit 1 naming each mismatch.")
    v.add_argument("--seed", type=int, default=None, help="the sample's seed (default: a new one, printed)")
    v.add_argument("--families", type=int, default=None, metavar="N",
                   help="families to sample (default: make test's sample, dpe5g.simulation.verify.SAMPLE_FAMILIES)")
    v.add_argument("--trials", type=int, default=None, metavar="N",
                   help="trials per experiment (default: dpe5g.simulation.verify.SAMPLE_TRIALS)")
    v.add_argument("--all", action="store_true", help="every family (--trials of each stored experiment)")
    add_progress_options(v, "a progress bar per experiment")
    v


def add_own_city_options(tc) -> None:
    """``dpe5g trace``'s options of a city of one's own, traced into a folder of one's own (``--out``)."""
    from ..city.trace import SCENES, CitySpec

    book = CitySpec()
    own = tc.add_argument_group(
        "a city of your own", "Traced into --out DIR (DIR/cities/NAME.npz, NAME.json, NAME_deployment.json); then "
        "`dpe5g run --channel traced --city DIR` runs the receivers on it.  Without these options: the book's city, "
        "into the results store.")
    own.add_argument("--out", default=None, metavar="DIR", help="the folder of your city (not the results store)")
    own.add_argument("--name", default="mycity", help="its name (default: mycity)")
    own.add_argument("--scene", default=None, metavar="NAME|FILE.xml",
                     help=f"one of Sionna RT's cities ({', '.join(SCENES)}; default {book.scene}) or a Mitsuba XML "
                          "scene file of yours (its materials Sionna RT's ITU radio materials)")
    own.add_argument("--deployment", default=None, metavar="FILE",
                     help="your BSs and region (see `dpe5g deployment --help`; one power_dbm for all BSs); default: "
                          "--density BSs placed in the most built-up square of side --side, as the book places them")
    own.add_argument("--density", type=float, default=None, metavar="PER_KM2",
                     help=f"BSs per km2 placed (default: the paper's {book.n_bs / book.side_m ** 2 * 1e6:.0f})")
    own.add_argument("--side", type=float, default=None, metavar="M",
                     help=f"side of the square region, metres (default: the paper's {book.side_m:.1f})")
    own.add_argument("--ues", type=int, default=None, metavar="N",
                     help=f"outdoor UE positions traced (default {book.n_ue})")
    own.add_argument("--max-depth", type=int, default=None, metavar="K",
                     help=f"most interactions per path (default {book.max_depth})")
    own.add_argument("--samples", type=int, default=None, metavar="N",
                     help=f"rays shot per BS (default {book.samples_per_src})")
    own.add_argument("--scattering", type=float, default=None, metavar="S",
                     help=f"scattering coefficient of every material, 0 to 1; 0 traces no diffuse reflection "
                          f"(default {book.scattering_coefficient:g}, the book's)")
    own.add_argument("--refraction", action="store_true", default=None, help="trace transmission through walls")
    own.add_argument("--edge-diffraction", action="store_true", default=None,
                     help="Sionna RT's diffraction on free edges too")
    own.add_argument("--seed", type=int, default=None, help=f"placements' and solver's seed (default {book.seed})")


def add_info_commands(sub) -> None:
    """``dpe5g profile``, ``deployment`` and ``scene``."""
    t = sub.add_parser("profile", help="print a TR 38.901 TDL profile scaled to a delay spread")
    t.add_argument("name", help="A, B, C, D or E")
    t.add_argument("--delay-spread", type=float, default=65e-9, metavar="S",
                   help="desired RMS delay spread in SECONDS (65e-9)")
    t.add_argument("--k-factor-db", type=float, default=None, help="K-factor override for D/E, dB")
    t

    from ..phy.deployment import EXAMPLES, FORMAT

    d = sub.add_parser("deployment", help="check a deployment file (JSON or CSV) and print a summary",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description=textwrap.fill(FORMAT, 100),
                       epilog="\n".join(f"A {k.upper()} example (dpe5g deployment --example {k} > mine.{k}):\n\n"
                                         + textwrap.indent(v, "  ") for k, v in EXAMPLES.items()))
    d.add_argument("path", nargs="?", default="tst",
                   help="path, or a packaged deployment: 'tst' (default), 'ring', 'ring-wide'")
    d.add_argument("--example", choices=sorted(EXAMPLES), default=None,
                   help="print an example deployment file in this format (the same BSs and region in each) and exit")
    d

    s = sub.add_parser("scene", help="export the meshcat 3-D scene of the urban example as a static HTML file",
                       description="The deployment's buildings and BSs, an example UE with its nearest links "
                                   "(LoS/NLoS from eq. (11)) and the correlogram of its DPE fix, as one offline HTML "
                                   "page; ours (Figs. 7-8) by default.")
    s.add_argument("--deployment", default=None, metavar="FILE",
                   help="a deployment file, JSON or CSV (see `dpe5g deployment`), or a packaged one ('tst', 'ring', "
                        "'ring-wide'); default: ours, as in Figs. 7-8")
    s.add_argument("--out", default="urban_scene.html", metavar="FILE.html",
                   help="output HTML file (default: urban_scene.html); an existing file is kept unless --force")
    s.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    add_progress_options(s, "the steps (about 30 s for ours)")
    s
