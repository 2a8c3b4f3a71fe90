"""The results store checked against today's code: a random sample of stored trials recomputed, or every experiment.

``verify_sample`` recomputes a sample and compares every stored field; ``reproduce`` recomputes every stored
experiment and rewrites the store.

Trial t of an experiment depends only on its config, its seed and t (``trial_draw.trial_key``), so one trial recomputed
on its own equals the stored one.  A float agrees within ``VERIFY_RTOL`` of the stored value (the machine that
computed the store gives the same bits; another CPU may differ in the last ones: SIMD width, FFT plans), NaN where
NaN, and a relative difference of costs (``ABSOLUTE_FIELDS``) within ``VERIFY_RTOL`` absolute; integers and booleans
must be equal.
"""

from __future__ import annotations

import random
import sys
import time
from dataclasses import dataclass
from math import comb
from pathlib import Path

import numpy as np

from ..common.errors import DamagedEntry
from ..common.locations import store_root
from ..receivers import otdoa
from . import engine, store, trials
from .experiment import Experiment

#: a recomputed float agrees with the stored one within this relative difference: about 4.5 million float64 steps,
#: for CPUs that differ in the last bits, and 1000 times below the figure-diff's tolerance (1e-6)
VERIFY_RTOL = 1e-9
#: fields that are a relative difference of two costs, (a − b) / b (the certified search's gap): a relative error of
#: VERIFY_RTOL in a and b moves them by about VERIFY_RTOL absolutely, however small they are, so they are compared
#: within VERIFY_RTOL absolute (a gap of 1e-7 recomputed on an AVX-512 CPU differs from the store by 1.4e-16)
ABSOLUTE_FIELDS = ("gap",)
#: a position or distance (fields ending in _m or _xyz) of an experiment that computes OTDoA fixes may differ by
#: ``otdoa.POSITION_ATOL_M`` absolutely (the OTDoA fix's last digits differ between CPUs)
OTDOA_POSITION_FIELDS = ("_m", "_xyz")
#: the sample ``make test`` recomputes (``tests/simulation/test_store.py``, ``dpe5g verify``): two trials of every experiment in
#: three random families; the compiles of a family are its cost (book/running.md, "The results store")
SAMPLE_FAMILIES, SAMPLE_TRIALS = 3, 2


@dataclass(frozen=True)
class Mismatch:
    """A stored trial whose field differs from what the code computes today; ``str()`` gives its one-line report.

    Attributes
    ----------
    experiment : str
        The experiment's name.
    trial : int
        The trial; -1 for the whole entry, or a whole field whose dtype or shape differs.
    field : str
        The stored field ("entry" for the entry itself).
    stored, computed : str
        The stored and the computed value (or dtype and shape), as text.
    message : str
        The whole line, where the entry itself is at fault (damaged); "" otherwise.
    """

    experiment: str
    trial: int
    field: str
    stored: str
    computed: str
    message: str = ""  # the whole line, where the entry itself is at fault (damaged)

    def __str__(self) -> str:
        return self.message or (
            f"results store: {self.experiment}, trial {self.trial}, field {self.field}: stored {self.stored}, "
            f"computed {self.computed}; run `make reproduce` to recompute the store from today's code")


def differences(name: str, rows, stored: dict, computed: dict, position_atol_m: float = 0.0) -> list[Mismatch]:
    """The (trial, field) pairs of ``computed`` that differ from ``stored``.

    A float differs beyond ``VERIFY_RTOL``, relative, and absolute too for ``ABSOLUTE_FIELDS``; beyond
    ``position_atol_m`` absolute too for the positions and distances (``OTDOA_POSITION_FIELDS``).

    Parameters
    ----------
    name : str
        The experiment's name, for the report.
    rows : sequence of int
        The trial index of each row.
    stored, computed : dict
        {field: array}, trials on the leading axis.
    position_atol_m : float
        Absolute tolerance of positions and distances, metres (``position_atol`` of the experiment).

    Returns
    -------
    list of Mismatch
        One per (trial, field) that differs (its first differing element).
    """
    out = []
    for k in sorted(stored):
        s = np.asarray(stored[k])
        c = np.asarray(computed[k])
        if s.shape != c.shape or s.dtype != c.dtype:
            out.append(Mismatch(name, -1, k, f"{s.dtype} {s.shape}", f"{c.dtype} {c.shape}"))
            continue
        if np.issubdtype(c.dtype, np.floating):
            atol = (VERIFY_RTOL if k in ABSOLUTE_FIELDS else
                    position_atol_m if k.endswith(OTDOA_POSITION_FIELDS) else 0.0)
            ok = np.isclose(s, c, rtol=VERIFY_RTOL, atol=atol) | (np.isnan(s) & np.isnan(c))
        else:
            ok = s == c
        for i in np.unique(np.nonzero(~ok.reshape(len(ok), -1))[0]):
            j = int(np.argmax(~ok[i].reshape(-1)))
            out.append(Mismatch(name, int(rows[i]), k, repr(s[i].reshape(-1)[j].item()),
                                repr(c[i].reshape(-1)[j].item())))
    return out


def position_atol(e: Experiment) -> float:
    """The absolute tolerance of ``e``'s positions and distances.

    Parameters
    ----------
    e : Experiment
        The experiment.

    Returns
    -------
    float
        ``otdoa.POSITION_ATOL_M`` (metres) where it computes OTDoA fixes or centres its window on them, else 0
        (relative ``VERIFY_RTOL`` only).
    """
    return otdoa.POSITION_ATOL_M if e.receiver.otdoa or e.receiver.centring == "otdoa" else 0.0


def recompute(e: Experiment, picked) -> dict:
    """``e``'s trials ``picked`` computed now, each on its own, full precision.

    Parameters
    ----------
    e : Experiment
        The experiment.
    picked : sequence of int
        Trial indices.

    Returns
    -------
    dict
        {field: (T, ...)}, the stored fields.
    """
    runner = engine.ChunkRunner(e)
    batch = engine.BATCH_SIZE[e.receiver.search.method]
    parts = [runner(t, t + 1, batch, workers=1) for t in picked]
    return {k: np.concatenate([p[k] for p in parts]) for k in store.stored_fields(e)}


def family(e: Experiment) -> tuple:
    """The programs whose compiles dominate ``e``'s cost: experiments of one family share their compiles.

    So recomputing a trial of each experiment of a family costs little more than one.

    Parameters
    ----------
    e : Experiment
        The experiment.

    Returns
    -------
    tuple
        ``trials.program_config`` of each program: the searches and the OTDoA detector (the prior's draw compiles in
        moments).
    """
    progs = ("bnb_prep", "bnb_fix") if e.receiver.search.method == "bnb" else ("grid_trial",)
    progs += ("toa",) if e.receiver.otdoa else ()
    return tuple(trials.program_config(e, p) for p in progs)


def families(experiments) -> list[list[Experiment]]:
    """The experiments grouped by ``family``, in the order each family first appears.

    Parameters
    ----------
    experiments : iterable of Experiment
        The experiments.

    Returns
    -------
    list of list of Experiment
        The families.
    """
    groups: dict = {}
    for e in experiments:
        groups.setdefault(family(e), []).append(e)
    return list(groups.values())


def sample(seed: int, n_families: int, n_trials: int, experiments) -> list[tuple[Experiment, list[int]]]:
    """The sample ``verify_sample`` recomputes, all drawn from ``random.Random(seed)``.

    Parameters
    ----------
    seed : int
        The draws' seed.
    n_families : int
        Families (``families``) of the stored experiments, drawn without replacement.
    n_trials : int
        Trials of every experiment in them.
    experiments : list of Experiment
        The experiments to draw from (``catalog.store_experiments()``: every stored one).

    Returns
    -------
    list of (Experiment, list of int)
        Each experiment with its trials.
    """
    rng = random.Random(seed)
    groups = families(experiments)
    picks = rng.sample(range(len(groups)), min(n_families, len(groups)))
    return [(e, sorted(rng.sample(range(e.run.n_trials), min(n_trials, e.run.n_trials))))
            for i in picks for e in groups[i]]


def verify_sample(seed: int, experiments, n_families: int = SAMPLE_FAMILIES, n_trials: int = SAMPLE_TRIALS,
                  log=sys.stderr, report=None) -> tuple[list[Mismatch], list[tuple[str, list[int]]]]:
    """Recompute ``sample(seed, n_families, n_trials, experiments)`` and compare it with the store.

    An experiment the store lacks, or whose entry is damaged (``errors.DamagedEntry``), is itself a mismatch (field
    "entry").

    Parameters
    ----------
    seed, experiments, n_families, n_trials
        As in ``sample``.
    log : file or None
        Where to print each experiment's time; None: nowhere.
    report : callable or None
        Called with each ``Mismatch`` as soon as it is found (the command line prints it then, so that a check cut off
        part-way has still told what it found).

    Returns
    -------
    mismatches : list of Mismatch
        Every difference found.
    done : list of (str, list of int)
        (experiment name, trials recomputed).
    """
    out, done = [], []
    for e, picked in sample(seed, n_families, n_trials, experiments):
        t0 = time.perf_counter()
        try:
            hit = store.stored(e)
            held = None if hit is None else hit.load(trials=picked)
        except DamagedEntry as err:
            hit, found = None, [Mismatch(e.run.name, -1, "entry", "damaged", err.reason, str(err))]
        else:
            found = ([Mismatch(e.run.name, -1, "entry", "none", f"{e.run.n_trials} trials asked")] if hit is None
                     else differences(e.run.name, picked, held, recompute(e, picked), position_atol(e)))
        out += found
        for m in found if report is not None else ():
            report(m)
        if hit is None:  # nothing recomputed: the entry is missing or damaged
            continue
        done.append((e.run.name, picked))
        if log is not None:
            print(f"verify: {e.run.name} trials {picked} recomputed ({time.perf_counter() - t0:.1f} s)", file=log)
    return out, done


def coverage_runs(n_stored: int, n_per_run: int, quantile: float = 0.95) -> tuple[float, int]:
    """Runs of ``verify_sample`` until every family, so every stored experiment, has been verified at least once.

    Exact up to rounding, from the chain of the number of families not yet drawn: a run that finds k of them undrawn
    draws i of those with the hypergeometric probability C(k, i) C(n − k, m − i) / C(n, m) (all terms positive, so no
    cancellation, unlike inclusion–exclusion over the families never drawn).

    Parameters
    ----------
    n_stored : int
        Families n.
    n_per_run : int
        Distinct families m a run draws (independent seeds).
    quantile : float
        The quantile of the runs reported.

    Returns
    -------
    mean : float
        The mean number of runs.
    q_point : int
        The ``quantile`` point of the number of runs.
    """
    n, m = n_stored, min(n_per_run, n_stored)
    step = np.zeros((n + 1, n + 1))  # step[k, k - i]: P(k undrawn → k - i undrawn)
    for k in range(n + 1):
        for i in range(0, min(k, m) + 1):
            step[k, k - i] = comb(k, i) * comb(n - k, m - i) / comb(n, m)
    dist = np.zeros(n + 1)
    dist[n] = 1.0
    mean, r, cdf, q_point = 0.0, 0, 0.0, None
    while cdf < 1 - 1e-12 and r < 100_000:
        r += 1
        dist = dist @ step
        mean += r * (dist[0] - cdf)
        cdf = dist[0]
        if q_point is None and cdf >= quantile:
            q_point = r
    return mean, q_point


def reproduce(experiments, progress: bool = True, client=None, log=sys.stdout) -> list[Mismatch]:
    """Recompute stored experiments from their seeds, report the trials that differ from the store, then rewrite it.

    The cache's chunks of today's code are reused: they are what this code computes.  A damaged entry is replaced
    without being read, and a damaged file that is none of the experiments' entries (a stray or stale file, which would
    stop every later read of the store) is removed.

    Parameters
    ----------
    experiments : iterable of Experiment
        The experiments (``catalog.store_experiments()``: every stored one, what ``dpe5g reproduce`` passes).
    progress : bool
        Show each run's progress bar.
    client : distributed.Client or None
        A Dask client (``cluster``); None: this process computes.
    log : file
        Where to print each experiment's line.

    Returns
    -------
    list of Mismatch
        The mismatches found (before rewriting).
    """
    exps = list(experiments)
    found = []
    t_all = time.perf_counter()
    for i, e in enumerate(exps, 1):
        t0 = time.perf_counter()
        res = engine.run(e, progress=progress, use_store=False, client=client)
        arrays = {k: getattr(res, k) for k in store.stored_fields(e)}
        try:  # (a damaged entry is replaced, never read)
            old = store.stored(e)
            held = None if old is None else old.load(e.run.n_trials)
            state = "new entry" if old is None else None
        except DamagedEntry as err:
            held, state = None, f"replaces a damaged entry ({err.reason})"
        diffs = [] if held is None else differences(e.run.name, range(e.run.n_trials), held, arrays, position_atol(e))
        found += diffs
        store.write_stored(e, arrays)
        state = state or f"{len(diffs)} differences from the store"
        print(f"[{i}/{len(exps)}] {e.run.name}: {e.run.n_trials} trials, {state} "
              f"({time.perf_counter() - t0:.1f} s)", file=log, flush=True)
        for d in diffs[:5]:
            print(f"    {d.experiment} trial {d.trial} {d.field}: stored {d.stored}, computed {d.computed}", file=log)
    known = {f"{e.run.name}-{e.config_key()}" for e in exps}
    root = store_root()
    strays = store.damaged_entries(root) if root is not None and root.is_dir() else []
    for err in strays:  # damaged entries of no experiment (stray or stale): nothing could read them; cities: trace
        path = Path(err.path)
        if path.name[: -len(path.suffix)] in known:
            continue
        for p in (path, path.with_suffix(".npz" if path.suffix == ".json" else ".json")):
            p.unlink(missing_ok=True)
        print(f"reproduce: removed {path.name} and its partner, damaged and of no stored experiment ({err.reason})",
              file=log, flush=True)
    print(f"reproduce: {len(exps)} experiments recomputed and stored, {len(found)} (trial, field) differences "
          f"({time.perf_counter() - t_all:.1f} s)", file=log, flush=True)
    return found
