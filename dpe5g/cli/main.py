"""Command line: ``dpe5g run`` (a Monte Carlo DPE study on your deployment), ``dpe5g figures`` (the figure build
script), ``dpe5g warm`` (fill the Monte Carlo cache), ``dpe5g reproduce`` and ``dpe5g verify`` (rewrite the results
store from today's code, or check a sample of it), ``dpe5g profile`` (print a scaled TDL table), ``dpe5g deployment``
(check and summarise a deployment file) and ``dpe5g scene`` (export the 3-D scene as HTML).  ``run``, ``warm`` and
``reproduce`` take ``--scheduler`` / ``--workers`` to run on a Dask cluster (``cluster``).

Bad input, including a file that cannot be read or written, ends with one line on stderr that names the parameter
and exit code 2, never a traceback; a failure that is not the input's (a damaged results store, a Dask cluster that
lost work or runs other code: ``errors.Failure``) with one line and exit code 1; Ctrl-C and SIGTERM with one line and
exit code 130 and 143, removing any file half-written.
"""

from __future__ import annotations

import math
import os
import re
import signal as os_signal  # (the name signal is dpe5g.phy.signal)
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from ..common._io import finish_publish, output_file, writable_dir
from ..common.locations import BASELINE_DIR, store_root
from .parser import UsageError, build_parser, numbers_as_values


#: library parameter → the ``dpe5g run`` option that sets it, so an error raised by the library names the option
RUN_OPTIONS = {"n_trials": "--trials", "snr_db": "--snr", "snrs_db": "--snr", "m_values": "--m", "n_taps": "--taps",
               "delay_spread_s": "--delay-spread", "centring": "--centring", "prior_scale_m": "--prior-sigma",
               "seed": "--seed", "deployment file": "--deployment", "prs_reuse": "--reuse", "los_mode": "--los-mode",
               "nlos_excess_median_s": "--nlos-excess", "dpe_nlos": "--dpe-nlos", "otdoa_nlos": "--otdoa-nlos",
               "channel 'traced'": "--channel traced"}


# ---- shared checks --------------------------------------------------------------------------------------------------

def show_progress(args) -> bool:
    """Whether a command shows its progress (``parser.add_progress_options``): with --progress, never with --quiet,
    else when stderr is a terminal."""
    if getattr(args, "quiet", False):
        return False
    return bool(getattr(args, "progress", None)) or sys.stderr.isatty()


def _in_baselines(folder: Path) -> bool:
    """Whether ``folder`` (resolved) is the committed baselines folder or inside it."""
    return folder.resolve().is_relative_to(BASELINE_DIR.resolve())


# ---- dpe5g run ------------------------------------------------------------------------------------------------------

def _with_option(err: ValueError, options: dict[str, str]) -> ValueError:
    """``err`` with the command-line option of the library parameter its message starts with put in front."""
    msg = str(err)
    for name, option in options.items():
        if re.match(rf"{re.escape(name)}\b", msg):
            return ValueError(f"{option}: {msg}")
    return err


def default_m_values(n_bs: int, snr_mode: str = "fixed") -> tuple[int, ...]:
    """``dpe5g run``'s M values when ``--m`` is not given, for a deployment of ``n_bs`` base stations.

    Parameters
    ----------
    n_bs : int
        The deployment's number of base stations (≥ 3).
    snr_mode : str
        "fixed" (Fig. 9's set-up) or "link_budget" (Fig. 10's).

    Returns
    -------
    tuple of int
        Fig. 9's M = 6, 12, 18, 24 that fit the deployment, then ``n_bs`` itself where it is below 24 (all of a
        small deployment's links); Fig. 10's M = 4 with snr_mode "link_budget" (``n_bs`` if fewer).
    """
    from ..studies import paper
    from ..simulation.experiment import Experiment

    if snr_mode == "link_budget":
        fig10_m = paper.fig10(1)[(paper.FIG10_CASES[0], "prior")].receiver.m_values
        return tuple(min(m, n_bs) for m in fig10_m)
    fig9_m = Experiment().receiver.m_values
    fits = tuple(m for m in fig9_m if m <= n_bs)
    return fits if n_bs >= max(fig9_m) or n_bs in fits else fits + (n_bs,)


def run_experiment(args):
    """The ``experiment.Experiment`` of ``dpe5g run``'s arguments.

    The paper's Fig. 9 set-up (``dpe5g.studies.paper``), or Fig. 10's link budget (``--snr-mode link-budget``), with the
    user's deployment, SNRs (dB), M values, trials, receiver window L (taps), delay spread (s), centring, prior σ (m)
    and seed.  Centring "truth" uses the paper's coarse-to-fine grid (``search_config.SearchConfig()``), "prior" and
    "otdoa" the honest certified search (``paper.honest_search()``), as the figures do.  When everything equals one
    of the paper's experiments, that experiment (and its cache) is used.

    Parameters
    ----------
    args : argparse.Namespace
        ``dpe5g run``'s parsed options (``cli_parser.add_run``).

    Returns
    -------
    Experiment
        The study to run.

    Raises
    ------
    ValueError
        An option out of its range or at odds with another, its message starting with the option's name.
    """
    from dataclasses import replace

    from ..phy import deployment, signal
    from ..receivers import search_config
    from ..studies import paper
    from ..simulation.experiment import Experiment

    dep = run_deployment(args)
    snr_mode = _check_run_options(args)
    prior_sigma = paper.PRIOR_SIGMA_M if args.prior_sigma is None else args.prior_sigma
    try:
        n_bs = deployment.named(dep).n_bs
        m_values = tuple(args.m) if args.m is not None else default_m_values(n_bs, snr_mode)
        snrs = () if snr_mode == "link_budget" else tuple(Experiment().links.snrs_db if args.snr is None
                                                            else args.snr)
        for snr in snrs:
            signal.check_snr_db(snr)  # one by one, so that the message shows the bad value
        search = search_config.SearchConfig(n_taps=args.taps) if args.centring == "truth" else replace(paper.honest_search(),
                                                                                             n_taps=args.taps)
        kw = dict(n_trials=args.trials, seed=args.seed, snrs_db=snrs, m_values=m_values, snr_mode=snr_mode,
                  delay_spread_s=args.delay_spread, centring=args.centring, search=search, deployment=dep,
                  channel=args.channel)
        if args.centring != "truth":
            kw.update(prior_kind="gaussian", prior_scale_m=prior_sigma)
        if args.reuse and snr_mode == "fixed":  # interference needs each BS's power: --snr is the nearest link's SNR
            kw.update(prs_reuse=args.reuse, snr_mode="nearest")
        elif args.reuse:
            kw.update(prs_reuse=args.reuse)
        kw.update(nlos_settings(args))
        e = Experiment.build(name="run", otdoa=args.centring == "otdoa", **kw)
        e.load_deployment()  # the file, and M against its BS count
    except ValueError as err:
        raise _with_option(err, RUN_OPTIONS) from None
    for known in (paper.fig9_honest(args.trials), paper.fig9_truth(args.trials),
                  paper.fig9_power(args.trials, args.reuse)):
        if e.replace(name=known.run.name) == known:
            return known
    return e


def run_deployment(args) -> str:
    """``dpe5g run``'s deployment: --deployment (a packaged name, or a file's absolute path), or with --channel
    traced the traced city of --city (``traced_city``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options.

    Returns
    -------
    str
        ``Scenario.deployment``.
    """
    from ..phy import deployment

    if args.channel not in ("tdl", "traced"):
        raise ValueError(f"--channel must be one of tdl, traced; got {args.channel!r}")
    if args.channel == "traced":
        if args.deployment is not None:
            raise ValueError("--deployment does not apply to --channel traced: the city's BSs are its own (--city)")
        if args.city is None:
            raise ValueError("--channel traced needs --city: a folder `dpe5g trace --out DIR` wrote, or 'munich' "
                             "(the book's city, in the results store)")
        return traced_city(args.city)
    if args.city is not None:
        raise ValueError("--city applies to --channel traced")
    name = args.deployment or "tst"
    return name if deployment.builtin(name) else str(Path(name).resolve())


def traced_city(city: str) -> str:
    """The deployment of the traced city ``--city`` names (``city.dataset.city_at``): a city of the results store by
    name; a city's deployment file; or a folder ``dpe5g trace --out`` wrote, holding one city.

    Parameters
    ----------
    city : str
        --city.

    Returns
    -------
    str
        A name, or the absolute path of the city's deployment file.
    """
    from ..city import dataset as city_paths

    path = Path(city)
    if path.is_dir():
        folder = path / city_paths.CITY_FOLDER
        found = sorted({p.name.removesuffix("_deployment.json")  # (a city being published too: its pending file)
                        for p in (*folder.glob("*_deployment.json"), *folder.glob(".*.publish/*_deployment.json"))})
        if len(found) != 1:
            raise ValueError(f"--city {city}: {city_paths.CITY_FOLDER}/ in it holds {len(found)} traced cities "
                             f"({', '.join(found) or 'none'}); give one city's deployment file, {city}/"
                             f"{city_paths.CITY_FOLDER}/<name>_deployment.json, or trace one there "
                             f"(dpe5g trace --out {city})")
        path = folder / f"{found[0]}_deployment.json"
    dep = str(path.resolve()) if path.suffix == ".json" else city
    name, root = city_paths.city_at(dep)
    if (damage := city_paths.check_city(name, root)) is not None:
        raise ValueError(f"--city {city}: {damage}")
    return dep


def nlos_settings(args) -> dict:
    """The experiment settings of ``dpe5g run``'s LoS and NLoS options (``parser.add_nlos_options``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options.

    Returns
    -------
    dict
        Settings of ``Experiment.build``: los_mode; the excess-delay law of the row --nlos-excess names; with
        --dpe-nlos the NLoS-aware DPE, its clock window widened by the law it assumes (the scenario's, else UMi's);
        with --otdoa-nlos the NLoS-aware OTDoA.
    """
    from ..phy.propagation import TR38901_EXCESS_DELAY

    out = {"los_mode": args.los_mode}
    if args.nlos_excess != "none":
        row = TR38901_EXCESS_DELAY.get(args.nlos_excess)
        if row is None:
            raise ValueError(f"--nlos-excess must be one of none, {', '.join(TR38901_EXCESS_DELAY)}; got "
                             f"{args.nlos_excess!r}")
        out.update(nlos_excess_median_s=row.median_s, nlos_excess_sigma_lg=row.sigma_lg)
    if args.dpe_nlos:
        if args.centring == "truth":
            raise ValueError("--dpe-nlos searches the certified window of an honest receiver: use --centring prior "
                             "or --centring otdoa, not truth")
        out.update(dpe_nlos=True, clock_window="clock_nlos",
                   nlos_prior="scenario" if args.nlos_excess != "none" else "umi")
    if args.otdoa_nlos:
        if args.centring != "otdoa":
            raise ValueError(f"--otdoa-nlos runs the NLoS-aware OTDoA on the OTDoA receiver's ToAs: use --centring "
                             f"otdoa (got {args.centring})")
        out.update(otdoa_nlos=True)
    return out


def _check_run_options(args) -> str:
    """The options of ``dpe5g run`` that depend on each other; returns the experiment's snr_mode."""
    modes = {"fixed": "fixed", "link-budget": "link_budget"}
    if args.snr_mode not in modes:
        raise ValueError(f"--snr-mode must be one of fixed, link-budget; got {args.snr_mode!r}")
    if args.snr_mode == "link-budget" and args.snr is not None:
        raise ValueError("--snr does not apply to --snr-mode link-budget (each link's SNR comes from its BS's "
                         "power_dbm and the path loss)")
    if args.reuse and args.centring == "truth":
        raise ValueError(f"--reuse {args.reuse} needs the honest receiver's certified search: use --centring prior "
                         f"or --centring otdoa, not truth")
    if args.prior_sigma is not None and args.centring != "prior":
        raise ValueError(f"--prior-sigma applies to --centring prior only (got --centring {args.centring})")
    if args.prior_sigma is not None and not (math.isfinite(args.prior_sigma) and 0 < args.prior_sigma <= 1000):
        raise ValueError(f"--prior-sigma must be in (0, 1000] m, got {args.prior_sigma!r} (for no prior error, use "
                         f"--centring truth)")
    return modes[args.snr_mode]


def _run(args) -> int:
    from ..simulation import engine, store
    from ..figures import tables as report
    from ..common._io import atomic_target

    e = run_experiment(args)
    out = output_file("--out", args.out, (".csv",), force=args.force)
    for line in e.load_deployment().assumed:  # what reading the deployment file filled in
        print(f"deployment: {line}", flush=True)
    sidecar = out.with_suffix(".json")
    if sidecar.exists() and not args.force:
        raise ValueError(f"--out {args.out}: {sidecar.name} beside it (where its provenance goes) exists; pass --force "
                         f"to overwrite both")
    with _cluster(args) as client:
        res = engine.run(e, progress=show_progress(args), client=client)
    try:  # an existing file is never left half-overwritten; without --force, never replaced
        with atomic_target(out, exclusive=not args.force) as tmp_csv:
            res.write_csv(tmp_csv)
            with atomic_target(sidecar, exclusive=not args.force) as tmp_json:
                res.write_provenance(tmp_json, store.git_commit())
    except FileExistsError:
        raise ValueError(f"--out {args.out}: another run wrote it meanwhile; the results of this one are in the "
                         f"cache: rerun with another --out, or --force to overwrite it") from None
    if threading.current_thread() is threading.main_thread():  # written: Ctrl-C now would only cut the summary
        os_signal.signal(os_signal.SIGINT, os_signal.SIG_IGN)
    n_rows = e.run.n_trials * e.n_snr * len(e.receiver.m_values)
    print(report.run_summary(res))
    print(f"wrote {out} ({n_rows} rows: one per trial, SNR and M) and {sidecar.name} (what produced it)")
    return 0


# ---- dpe5g figures --------------------------------------------------------------------------------------------------

def _figures(args) -> int:
    from ..common import _checks
    from ..simulation import store
    from ..figures import registry as figures
    from ..common.errors import Failure

    ids = args.only or list(figures.REGISTRY)
    for fig_id in ids:
        figures.get(fig_id)  # validate every id before spending time
    if args.trials is not None:
        _checks.integer("--trials", args.trials, 1, 10_000_000)
        if args.update_baselines:
            raise ValueError(f"--trials {args.trials} cannot be used with --update-baselines: the committed "
                             f"baselines use the paper's trial counts (dpe5g.studies.paper); write elsewhere with --out DIR")
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
    if any(figures.takes_trials(f) for f in ids) and (damaged := store.check_store()):  # before any figure
        more = f" ({len(damaged) - 1} more entries are damaged: `dpe5g verify` names them all)" if damaged[1:] else ""
        raise Failure(f"{damaged[0]}{more}")
    for fig_id in ids:
        t0 = time.perf_counter()
        trials = args.trials if args.trials is not None and figures.takes_trials(fig_id) else None
        png, js = figures.write(fig_id, out, progress=show_progress(args), trials=trials)
        print(f"{fig_id}: {png} {js} ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


# ---- dpe5g warm ------------------------------------------------------------------------------------------------------

def _warm(args) -> int:
    from ..simulation import engine
    from ..studies import catalog

    exps = catalog.store_experiments()
    order = exps if args.forward else exps[::-1]
    t0 = time.perf_counter()
    with _cluster(args) as client:
        for i, e in enumerate(order, 1):
            t = time.perf_counter()
            engine.run(e, progress=show_progress(args), reverse=not args.forward, client=client)
            print(f"[{i}/{len(order)}] {e.run.name}: {e.run.n_trials} trials ({time.perf_counter() - t:.1f} s)",
                  flush=True)
    print(f"warm: {len(order)} experiments in the cache ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


# ---- dpe5g reproduce, verify -----------------------------------------------------------------------------------------

def _reproduce(args) -> int:
    from ..simulation import store, verify
    from ..studies import catalog

    if store_root() is None:
        raise ValueError("DPE5G_STORE is 'off': reproduce rewrites the results store; unset it or name a folder")
    writable_dir("DPE5G_STORE", store_root())
    changed = store.code_changes()
    if changed and not args.allow_dirty:
        shown = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
        raise ValueError(f"reproduce: the code differs from its commit ({shown}); commit it first, so that every "
                         f"entry records the commit that computed it, or pass --allow-dirty (make reproduce "
                         f"ALLOW_DIRTY=1): the entries then record the commit and a digest of the changes")
    with _cluster(args) as client:
        found = verify.reproduce(catalog.store_experiments(), progress=show_progress(args), client=client)
    print(f"reproduce: {len(found)} stored (trial, field) values differed from today's code and were rewritten"
          if found else "reproduce: the store held what today's code computes", flush=True)
    return 0


def _trace(args) -> int:
    from ..city import dataset as city_paths, ray_tracer, trace as city_trace
    from ..studies import city as city_study, city_density, city_second, city_sensitivity

    from ..common import _checks

    _checks.integer("--chunk-batches", args.chunk_batches, 1, 10_000)  # (checked even where nothing is traced)
    if args.workers is not None:
        _checks.integer("--workers", args.workers, 1, 256)
    if args.out is not None or own_city_options(args):
        return _trace_own(args)
    root = store_root()
    if root is None:
        raise ValueError("DPE5G_STORE is 'off': dpe5g trace writes the traced city to a results store (unset it, or "
                         "name a folder)")
    writable_dir("DPE5G_STORE", root)  # the city goes to the store in use (locations.cities_dir)
    ray_tracer.use_backend(args.backend)  # the tracer's packages and its backend, checked before anything is traced
    spec, name = city_trace.CitySpec(), city_study.CITY
    finish_publish(city_paths.city_folder(), name)  # (a publication a stop cut short: finished first)
    retraced = args.force or not city_paths.is_current(name, spec.to_dict(), city_trace.code_digest())
    if not retraced:
        print(f"trace: {city_paths.city_file(name)} is whole and was traced with today's settings and code "
              "(--force traces it again)", flush=True)
    else:
        start = time.perf_counter()
        traced = _trace_chunks(args, spec)
        provenance = _trace_provenance(spec, start)
        path = city_paths.save_city(name, traced, spec.to_dict(), provenance)
        print(f"trace: {len(traced['link_ue'])} links of {spec.n_ue} UEs and {spec.n_bs} BSs traced, written to "
              f"{path} in {provenance['seconds']:.0f} s", flush=True)
    if retraced or not _view_whole(name):  # a current city's files stay as they are, byte for byte
        path = city_paths.save_view(name, _city_view(spec, name))
        print(f"trace: the 3-D view of its first trial's UE written to {path}", flush=True)
    city = city_paths.load_city(name)
    for line in city_sensitivity.trace_stale(city, args.force):  # the solver's settings tested
        print(f"trace: {line}", flush=True)
    for line in city_density.trace_stale(city, lambda spec: _trace_chunks(args, spec), _trace_provenance, args.force):
        print(f"trace: {line}", flush=True)  # the denser networks
    second, retraced = city_second.SECOND_CITY, args.force or not city_second.is_current()
    for line in city_second.trace_stale(lambda spec: _trace_chunks(args, spec), _trace_provenance, args.force):
        print(f"trace: {line}", flush=True)  # the second city
    if retraced or not _view_whole(second):
        path = city_paths.save_view(second, _city_view(city_second.second_spec(), second))
        print(f"trace: its 3-D view written to {path}", flush=True)
    return 0


def _trace_provenance(spec, start: float) -> dict:
    """What a traced city's record keeps of how it was traced: commit, tracing code, seconds since ``start`` (the
    batches read from the trace cache took none), the solver's calls (UEs per call, groups of BSs, one thread each:
    ``trace_chunks``), the ray tracer's libraries and its backend (Mitsuba variant)."""
    from ..city import ray_tracer, trace as city_trace
    from ..simulation import store

    return {"commit": store.git_commit(), "code": city_trace.code_digest(),
            "seconds": round(time.perf_counter() - start, 1), "ues_per_call": city_trace.ues_per_call(spec),
            "bs_groups": len(city_trace.bs_groups(spec.n_bs)), "solver_threads": 1,
            "libraries": ray_tracer.library_versions() | {"variant": ray_tracer.use_backend("auto")}}


def _trace_chunks(args, spec, region=None, bs_xyz=None) -> dict:
    """``trace_chunks.trace_city`` of ``spec``: in this process, or on the cluster of --scheduler / --workers; its
    batches cached as they are traced (.cache/trace), so that the same command resumes a stopped trace."""
    from ..city import trace_chunks

    with _cluster(args) as client:
        return trace_chunks.trace_city(spec, progress=show_progress(args), region=region, bs_xyz=bs_xyz, client=client,
                                       chunk_batches=args.chunk_batches)


#: ``dpe5g trace``'s options of a city of one's own (``parser.add_own_city_options``) → ``CitySpec`` fields
OWN_CITY = {"scene": "scene", "ues": "n_ue", "max_depth": "max_depth", "samples": "samples_per_src",
            "refraction": "refraction", "edge_diffraction": "edge_diffraction", "seed": "seed"}


def own_city_options(args) -> list[str]:
    """The options of a city of one's own given to ``dpe5g trace``, as typed."""
    given = [k for k in (*OWN_CITY, "deployment", "density", "side", "scattering") if getattr(args, k) is not None]
    return [f"--{k.replace('_', '-')}" for k in given] + (["--name"] if args.name != "mycity" else [])


def own_city_spec(args):
    """The ``CitySpec`` and the deployment (region, BS positions, or None: placed) of ``dpe5g trace``'s own city."""
    from ..city.trace import SCENES, CitySpec
    from ..phy import deployment

    book = CitySpec()
    kw = {field: getattr(args, opt) for opt, field in OWN_CITY.items() if getattr(args, opt) is not None}
    if kw.get("scene") is not None and kw["scene"] not in SCENES:
        kw["scene"] = str(Path(kw["scene"]).resolve())  # (recorded as an absolute path: the record says which file)
    if args.scattering is not None:
        kw.update(scattering_coefficient=args.scattering, diffuse_reflection=args.scattering > 0)
    if args.deployment is not None:
        if args.density is not None or args.side is not None:
            raise ValueError("--density and --side place BSs: not with --deployment, which gives them")
        dep = deployment.load_deployment(args.deployment)
        if len(set(dep.power_dbm.tolist())) != 1:
            raise ValueError(f"--deployment {args.deployment}: a traced city's BSs share one power_dbm (the traced "
                             f"paths are gains; the link budget adds the power), got {sorted(set(dep.power_dbm))}")
        x0, y0, x1, y1 = dep.region
        kw.update(n_bs=dep.n_bs, power_dbm=float(dep.power_dbm[0]), ue_height_m=dep.ue_height_m,
                  side_m=max(x1 - x0, y1 - y0))
        return CitySpec(**kw), dep.region, dep.bs_xyz
    side = book.side_m if args.side is None else args.side
    density = book.n_bs / book.side_m ** 2 * 1e6 if args.density is None else args.density
    if not (math.isfinite(side) and 50.0 <= side <= 2000.0):
        raise ValueError(f"--side must be in [50, 2000] m (side_m), got {side!r}")
    if not (math.isfinite(density) and 0 < density <= 1e5):
        raise ValueError(f"--density must be a positive number of BSs per km2 (at most 1e5), got {density!r}")
    kw.update(side_m=side, n_bs=round(density * side ** 2 / 1e6))
    try:
        return CitySpec(**kw), None, None
    except ValueError as err:
        if str(err).startswith("n_bs"):
            raise ValueError(f"--density {density:g} per km2 on a square of {side:g} m places {kw['n_bs']} BSs: "
                             f"{err}") from None
        raise


def own_city_inputs(spec, region, bs_xyz) -> str:
    """SHA-256 of what traces an own city beyond its ``CitySpec``: the given region and BSs (None: placed) and the
    bytes of a scene file of one's own (Sionna RT's scenes are the pinned package's), so that ``dpe5g trace --out``
    traces it again when either changed."""
    import hashlib

    import numpy as np

    from ..city import trace as city_trace

    h = hashlib.sha256(repr((None if region is None else [float(v) for v in region],
                             None if bs_xyz is None else np.asarray(bs_xyz, float).round(6).tolist())).encode())
    if spec.scene not in city_trace.SCENES:
        h.update(Path(city_trace.scene_file(spec.scene)).read_bytes())
    return h.hexdigest()


def _trace_own(args) -> int:
    """``dpe5g trace --out DIR``: a city of one's own, traced into DIR unless it is current there."""
    from ..city import dataset as city_paths, ray_tracer, trace as city_trace
    from ..common.locations import STORE_DIR

    if args.out is None:
        raise ValueError(f"{own_city_options(args)[0]}: a city of your own needs --out DIR, its folder (the results "
                         f"store holds the book's city only; make reproduce traces it)")
    dest = Path(args.out).resolve()
    for kept in {STORE_DIR.resolve(), *([store_root().resolve()] if store_root() is not None else [])}:
        if dest.is_relative_to(kept):
            raise ValueError(f"--out {args.out} is in the results store ({kept}); give a folder of your own")
    spec, region, bs_xyz = own_city_spec(args)
    name = city_paths.check_city_name("--name", args.name)
    writable_dir("--out", dest / city_paths.CITY_FOLDER, args.out)
    inputs = own_city_inputs(spec, region, bs_xyz)  # (a scene file of one's own: read, so it exists)
    ray_tracer.use_backend(args.backend)
    finish_publish(dest / city_paths.CITY_FOLDER, name)  # (a publication a stop cut short: finished first)
    if (not args.force and city_paths.is_current(name, spec.to_dict(), city_trace.code_digest(), dest)
            and city_paths.read_record(name, dest).get("inputs") == inputs):
        print(f"trace: {city_paths.city_file(name, dest)} is whole and was traced with these settings, scene, "
              "deployment and today's code (--force traces it again)", flush=True)
    else:
        start = time.perf_counter()
        traced = _trace_chunks(args, spec, region, bs_xyz)
        provenance = _trace_provenance(spec, start)
        path = city_paths.save_city(name, traced, spec.to_dict(), provenance, root=dest, extra={"inputs": inputs})
        print(f"trace: {len(traced['link_ue'])} links of {spec.n_ue} UEs and {spec.n_bs} BSs traced in "
              f"{provenance['seconds']:.0f} s, written to {path}", flush=True)
    print(f"trace: run the receivers on it: dpe5g run --channel traced --city {args.out} --trials N --out study.csv",
          flush=True)
    return 0


def _view_whole(name: str) -> bool:
    """Whether the stored 3-D view of the city ``name`` reads and matches its checksum."""
    from ..city import dataset as city_paths
    from ..common.errors import DamagedEntry

    try:
        city_paths.load_view(name)
    except DamagedEntry:
        return False
    return True


def _city_view(spec, name: str) -> dict:
    """The 3-D view of the city chapter: the buildings and the traced paths of trial 0's UE from its links' BSs."""
    from ..city import dataset as city_paths, trace as city_trace, view as city_view
    from ..simulation import traced_draw
    from ..studies import city as city_study

    city = city_paths.load_city(name)
    _, links = traced_draw.population(city_study.city_fig10(city_study.CITY_M[0], "otdoa", n_trials=1, city=name))
    u, bs = int(links.ue_index[0]), links.bs_index[0]
    scene = city_trace.load_scene(spec)
    return {"triangles": city_view.scene_triangles(scene, city.region), "ue": u, "ue_bs": bs} | \
        city_view.example_paths(scene, city.bs_xyz[bs], city.ue_xyz[u], spec)


def _verify(args) -> int:
    import random

    from ..common import _checks
    from ..common.errors import DamagedEntry
    from ..simulation import store, verify
    from ..studies import catalog

    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(2**31)
    _checks.integer("--seed", seed, 0, 2**31 - 1)
    families = verify.SAMPLE_FAMILIES if args.families is None else args.families
    n_trials = _checks.integer("--trials", verify.SAMPLE_TRIALS if args.trials is None else args.trials, 1, 10_000)
    n = None if args.all else _checks.integer("--families", families, 1, 10_000)
    damaged = store.check_store()  # every entry's checksum and row count: cheap, unlike recomputing its trials
    for err in damaged:
        print(err, file=sys.stderr)
    print(f"verify: every entry of the results store read, {len(damaged)} damaged", flush=True)
    try:  # (the city experiments' trials are counted on the stored cities: a damaged city stops the listing)
        exps = catalog.store_experiments()
    except (ValueError, DamagedEntry) as err:
        if not damaged:
            raise
        print(f"verify: no trial recomputed: the stored experiments cannot be listed while the store is damaged "
              f"({_one_line(err)})", file=sys.stderr, flush=True)
        return 1
    n = len(exps) if n is None else n
    print(f"verify: seed {seed} (dpe5g verify --seed {seed} repeats this sample)", flush=True)
    def report(m):  # each mismatch as soon as it is found; a damaged entry was named above
        if m.field != "entry" or m.stored != "damaged":
            print(m, file=sys.stderr, flush=True)

    found, done = verify.verify_sample(seed, exps, n, n_trials, report=report,
                                       log=sys.stderr if show_progress(args) else None)
    total = sum(len(t) for _, t in done)
    print(f"verify: {total} trials of {len(done)} experiments recomputed, {len(found)} mismatches", flush=True)
    return 1 if found or damaged else 0


@contextmanager
def _cluster(args):
    """The Dask client of --scheduler / DPE5G_SCHEDULER / --workers (``cluster.connect``), closed on exit; None
    (this process) without them.  While it runs, distributed's client logs only what is critical: a lost scheduler
    is told in the command's one line (``cluster.gather``), not also in the client's traceback of its reconnect."""
    import logging

    from ..common import cluster

    client = cluster.connect(args.scheduler, args.workers)
    log = logging.getLogger("distributed.client")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        yield client
    finally:
        try:
            cluster.close(client)
        finally:
            log.setLevel(level)


# ---- dpe5g profile, deployment, scene -------------------------------------------------------------------------------

def _profile(args) -> int:
    from ..phy import channel

    try:
        prof = channel.tdl_profile(args.name, args.delay_spread, args.k_factor_db)
    except ValueError as err:
        raise _with_option(err, {"delay_spread_s": "--delay-spread", "k_factor_db": "--k-factor-db"}) from None
    k = "" if prof.k_factor_db is None else f", K = {prof.k_factor_db:g} dB"  # (NLoS profiles have no K-factor)
    print(f"{prof.name} ({prof.table}) scaled to DS = {prof.delay_spread_s * 1e9:g} ns{k}")
    print(f"{'tap':>3} {'delay (ns)':>11} {'power (dB)':>11} {'kind':>9}")
    for i, (d, p, los) in enumerate(zip(prof.delays_s, prof.powers_db, prof.los)):
        print(f"{i:3d} {d * 1e9:11.3f} {p:11.2f} {'LoS' if los else 'Rayleigh':>9}")
    print(f"RMS delay spread of the scaled profile: {channel.rms_delay_spread(prof.delays_s, prof.powers) * 1e9:.3f} ns")
    return 0


def _deployment(args) -> int:
    import numpy as np

    from ..phy import deployment

    if args.example is not None:
        print(deployment.EXAMPLES[args.example], end="")
        return 0
    dep = deployment.named(args.path)
    for line in dep.assumed:
        print(f"{dep.name}: {line}")
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
    from ..figures import registry as figures, scene3d

    out = output_file("--out", args.out, (".html", ".htm"), force=args.force)
    step = (lambda text: print(f"scene: {text}", file=sys.stderr, flush=True)) if show_progress(args) else (
        lambda text: None)
    step("the deployment and its example UE (Fig. 7)")
    if args.deployment is None:  # ours: the figures' payloads, computed once and kept
        p7 = figures.compute("fig07_deployment_map")
        step("the example UE's correlogram, eq. (10) on 101 x 101 points (Fig. 8; about 25 s)")
        p8 = figures.compute("fig08_urban_correlogram")
    else:
        from ..figures import data as figure_data

        try:
            p7 = figure_data.deployment_payload(args.deployment)
            step("the example UE's correlogram, eq. (10) on 101 x 101 points (Fig. 8; about 25 s)")
            p8 = figure_data.urban_correlogram_payload(args.deployment)
        except ValueError as err:
            raise ValueError(f"--deployment: {err}") from None
    step("the 3-D scene")
    try:
        path = scene3d.export(p7, p8, out, exclusive=not args.force)
    except FileExistsError:
        raise ValueError(f"--out {args.out}: another process wrote it meanwhile; pass --force to overwrite "
                         f"it") from None
    print(f"wrote {path}")
    return 0


#: each subcommand's handler (``cli_parser.build_parser`` defines their options)
COMMANDS = {"run": _run, "figures": _figures, "warm": _warm, "reproduce": _reproduce, "trace": _trace,
            "verify": _verify, "profile": _profile, "deployment": _deployment, "scene": _scene}

_one_line = lambda text: " ".join(str(text).split())  # noqa: E731  (a message on one line)


#: the signals a command ends on at once, each with its exit code (128 + its number) and the word for it
STOP_SIGNALS = {os_signal.SIGINT: (130, "interrupted"), os_signal.SIGTERM: (143, "terminated")}


#: what a stopped command leaves, by command; the others keep their finished Monte Carlo chunks
KEPT_ON_STOP = {"trace": "nothing of this trace is kept, and each stored city is the old one or the new one whole "
                         "(published as one unit); the same command starts it again",
                "profile": "nothing was written", "deployment": "nothing was written",
                "scene": "nothing was written"}


def kept_on_stop(prog: str) -> str:
    """What the command ``prog`` ("dpe5g run", …) leaves when it is stopped, for its one line."""
    return KEPT_ON_STOP.get(prog.removeprefix("dpe5g").strip(),
                            "finished Monte Carlo chunks are cached; the same command resumes")


def _interrupted(prog: str, signum: int = os_signal.SIGINT):
    """Ctrl-C (SIGINT) or SIGTERM, at any moment of a command: the files being written are removed (every finished
    file is whole: ``_io.atomic_target``), one line, exit code 130 (143 for SIGTERM) at once.  Not a
    KeyboardInterrupt: raised inside a callback (JAX's garbage collection hook) or while threads finish, it was
    swallowed or ended the process unexplained."""
    from ..common._io import remove_in_flight

    code, word = STOP_SIGNALS.get(signum, STOP_SIGNALS[os_signal.SIGINT])
    remove_in_flight()
    sys.stdout.flush()
    bars = getattr(getattr(sys.modules.get("tqdm"), "tqdm", None), "_instances", None)  # a progress bar is drawn:
    sys.stderr.write("\n" if bars else "")  # end its line first
    sys.stderr.write(f"{prog}: {word} ({kept_on_stop(prog)})\n")
    sys.stderr.flush()
    os._exit(code)


def main(argv=None) -> int:
    """Run the command line; returns the exit code (0; 2 after one line on stderr for bad input; 1 after one line
    for a failure that is not the input's, ``errors.Failure``: a damaged results store, a Dask cluster that lost
    work or runs other code)."""
    from ..common.errors import Failure

    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    prog = "dpe5g"
    on_main = threading.current_thread() is threading.main_thread()
    previous = {}
    if on_main:
        for signum in STOP_SIGNALS:
            previous[signum] = os_signal.signal(signum, lambda n, frame: _interrupted(prog, n))
    try:
        args = parser.parse_args(numbers_as_values(argv))
        prog = f"dpe5g {args.command}"
        return COMMANDS[args.command](args)
    except UsageError as e:
        print(f"{e.prog}: error: {_one_line(e)}", file=sys.stderr)
    except ValueError as e:
        print(f"{prog}: error: {_one_line(e)}", file=sys.stderr)
    except Failure as e:
        print(f"{prog}: error: {_one_line(e)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # the reader of stdout left (`dpe5g profile D | head -1`): end quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as e:
        where = f": {e.filename}" if e.filename else ""
        print(f"{prog}: error: {_one_line(e.strerror or e)}{where}", file=sys.stderr)
    except KeyboardInterrupt:  # (called from another thread, where the handler above cannot be set)
        print(f"{prog}: interrupted ({kept_on_stop(prog)})", file=sys.stderr)
        return 130
    finally:  # give a caller in this process its handlers back; the command line's start-up handler stays replaced
        for signum, handler in previous.items():
            if getattr(handler, "__module__", None) != "dpe5g":
                os_signal.signal(signum, handler)
    return 2


def entry() -> None:
    """The ``dpe5g`` script and ``python -m dpe5g``: ``main``, its output in UTF-8 whatever the terminal's encoding
    (an ASCII locale no longer fails on the first σ after the results are written), then exit at once (output
    flushed, files closed), skipping the interpreter's shutdown, where a Ctrl-C would end the process with no
    word."""
    for stream in (sys.stdout, sys.stderr):  # the same bytes whatever the terminal's encoding (σ, µ, ±, ≥)
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(encoding="utf-8", errors="replace")
    code = main()
    sys.stdout.flush(), sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
