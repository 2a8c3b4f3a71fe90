"""The Monte Carlo engine (Section IV): runs an experiment's trials in batches (vmap) and threads, keeping the results.

The programs are compiled once per the part of the experiment they read (``trials.program_config``), and the
results are kept in the store (``chunk_cache.ChunkCache``): chunks already there are loaded, the others computed and
written as they finish.

Every draw of trial t comes from ``trial_draw.trial_key(seed, t)``, so results do not depend on the batch size, the chunk
size, the number of threads or which chunks come from the store.
"""

from __future__ import annotations

import json
import os
import pickle
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache, partial

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from ..common import _checks
from ..common.cluster import worker_address
from ..common.errors import Failure
from ..phy import deployment
from ..receivers import otdoa, otdoa_nlos, receiver
from . import trials
from .chunk_cache import ChunkCache, sliced_chunk, snr_superset_runs
from .cluster import OtherCode, gather
from .code_key import changed_since_import, code_version
from .experiment import OTDOA_DETECTORS, Experiment
from .results import Results
from .store import stored, stored_fields
from .trial_draw import trial_keys

#: trials vmapped together by ``run``, per search method (speed only; results do not depend on it): the grid search
#: runs the same steps for every trial and gains from batching; the certified search's loops run as long as the
#: slowest trial of a batch needs, so its fixes run one trial at a time whatever the batch size
#: (``ChunkRunner.bnb``), and so do its experiments' OTDoA step 1 and prior centres
BATCH_SIZE = {"grid": 2, "bnb": 1}
#: the detector whose ToAs the NLoS-aware OTDoA receiver reads (``otdoa_nlos``)
FIRST_PATH = OTDOA_DETECTORS.index("first_path")

_BUILDERS = {"grid_trial": trials.grid_trial_fn, "bnb_prep": trials.bnb_prep_fn, "toa": trials.toa_fn,
             "prior": trials.prior_fn}


def compiled_program(e: Experiment, program: str):
    """``e``'s program ``program``, one object per ``trials.program_config`` and deployment file content.

    So the runs of one process that share it trace and compile it once.

    Parameters
    ----------
    e : Experiment
        The experiment.
    program : str
        One of ``trials.PROGRAMS``.

    Returns
    -------
    callable
        The program (jitted).
    """
    key = trials.program_config(e, program)
    return _compiled(program, key, "" if program == "bnb_fix" else deployment.digest(e.scenario.deployment))


@lru_cache(maxsize=32)
def _compiled(program: str, key, digest: str):
    if program == "bnb_fix":
        return trials.bnb_fix_fn(*key)
    return _BUILDERS[program](key, key.load_deployment())


@partial(jax.jit, static_argnames=("fn",))
def run_batch(args, fn, shared=()):
    """``fn(*a, *shared)`` for each ``a`` of ``args``, vmapped over their leading axis (the batch).

    A batch of one trial calls ``fn`` on it directly (vmap would turn any while loop into a batched one that carries its
    state through a select at every step; the results are the same bits).

    Parameters
    ----------
    args : tuple of arrays (B, ...)
        Per-trial inputs, the batch on the leading axis.
    fn : callable
        The per-trial function (static: a new one compiles anew).
    shared : tuple
        Inputs passed to every call.

    Returns
    -------
    pytree of arrays (B, ...)
        ``fn``'s outputs, the batch on the leading axis.
    """
    if args[0].shape[0] == 1:
        return jax.tree.map(lambda o: o[None], fn(*(a[0] for a in args), *shared))
    return jax.vmap(lambda *a: fn(*a, *shared))(*args)


def run_chunk(args, fn, batch_size: int, shared=(), workers: int = 1) -> dict | tuple:
    """``fn(*a, *shared)`` for each ``a`` of ``args``, ``batch_size`` trials per call of one compiled batch function.

    The last batch is filled up by repeating its last trial, whose copies are dropped.  So the compiled program depends
    on the batch size, never on the chunk's length: a run of 3 trials reuses the executable of a run of 5000 (in this
    process, and through JAX's persistent cache in others).  A batch's result depends only on its trials, never on the
    thread or the order.

    Parameters
    ----------
    args : tuple of numpy.ndarray (T, ...)
        Per-trial inputs, trials on the leading axis.
    fn : callable
        The per-trial function.
    batch_size : int
        Trials per call.
    shared : tuple
        Inputs passed to every call.
    workers : int
        Batches computed at once, each in its own thread (XLA runs a call of the certified search's loops on one core,
        and releases the GIL while it runs); the first batch runs alone, so the program is traced and compiled once.

    Returns
    -------
    dict or tuple of numpy.ndarray (T, ...)
        ``fn``'s outputs, trials on the leading axis.
    """
    n = args[0].shape[0]

    def one(a):
        take = np.minimum(np.arange(a, a + batch_size), n - 1)
        out = run_batch(tuple(x[take] for x in args), fn, shared)
        return jax.tree.map(lambda o, k=min(batch_size, n - a): np.asarray(o)[:k], out)

    return jax.tree.map(lambda *p: np.concatenate(p), *threaded(one, range(0, n, batch_size), workers))


def threaded(fn, items, workers: int) -> list:
    """``[fn(i) for i in items]``, ``workers`` at once in threads, the first alone.

    The first runs alone so that what it compiles is compiled once, then shared by the threads.

    Parameters
    ----------
    fn : callable
        The function of one item.
    items : sequence
        Its arguments.
    workers : int
        Threads at once (1: all in this thread).

    Returns
    -------
    list
        ``fn``'s results, in the order of ``items``.
    """
    parts = [fn(items[0])]
    if len(items) > 1 and workers > 1:
        with ThreadPoolExecutor(min(workers, len(items) - 1)) as pool:
            parts += list(pool.map(fn, items[1:]))
    else:
        parts += [fn(i) for i in items[1:]]
    return parts


class ChunkRunner:
    """The compiled computation of a chunk of trials, called as ``runner(start, stop, batch_size, workers=1)``.

    OTDoA step 1 and its convex fixes (when the experiment asks), then the DPE fixes; built on first use (compiling is
    the slow part) and shared by every chunk of a run.  A call returns the chunk's fields of ``Results`` for trials
    start … stop-1.

    Parameters
    ----------
    e : Experiment
        The experiment whose chunks it computes.
    """

    def __init__(self, e: Experiment):
        self.e = e
        self.dep = e.load_deployment()
        self.bnb = e.receiver.search.method == "bnb"
        if self.bnb:  # two programs: the trial's draws and correlogram windows, then a fix per (SNR, M)
            self.prep = compiled_program(e, "bnb_prep")
            self.fix = compiled_program(e, "bnb_fix")
        else:
            self.fn = compiled_program(e, "grid_trial")
        self.toa_fn = compiled_program(e, "toa") if e.receiver.otdoa else None
        self.prior_fn = compiled_program(e, "prior") if e.receiver.centring == "prior" else None
        self.window = jnp.asarray(receiver.receiver_window(e.receiver_search(), e.scenario.prs_reuse)) if self.bnb else None
        # one compiled OTDoA problem per M, built once per run (``otdoa.Solver`` reads cvxpy's data map when built)
        self.solvers = {m: otdoa.Solver(m) for m in e.receiver.m_values} if e.receiver.otdoa else None
        self.nlos = otdoa_nlos.NlosSolver() if e.receiver.otdoa_nlos else None  # the NLoS-aware OTDoA receiver

    def __call__(self, start: int, stop: int, batch_size: int, workers: int = 1) -> dict:
        e = self.e
        keys = np.asarray(trial_keys(e.run.seed, start, stop))
        ts = np.arange(start, stop)  # the trial indices: a traced channel source reads trial t's UE (``draw.draw_fn``)
        if not e.receiver.otdoa:
            return self._dpe(keys, ts, None, batch_size, workers)
        # step 1 on the same signals (regenerated from the same keys), then the convex fixes, in pieces: the fixes of
        # piece k+1 (Python, one core) are solved while the DPE of piece k runs (XLA, the GIL released)
        out = run_chunk((keys, ts), self.toa_fn, batch_size, workers=workers)
        (toas, *sigma), ue, idx = out[:-2], out[-2], out[-1]  # σ (eq. (O1)) with ``otdoa_nlos``
        n = stop - start
        step = max(-(-n // self.OTDOA_PIECES), 1)
        ots, dpes = [], []
        with ThreadPoolExecutor(1) as background:
            for a in range(0, n, step):
                sl = slice(a, min(a + step, n))
                ot = trials.otdoa_fixes(e, self.dep, toas[sl], ue[sl], idx[sl], self.solvers)
                if sigma:  # ``otdoa_nlos``: the NLoS-aware receiver on the first-path ToAs
                    ot |= otdoa_nlos.chunk_fixes(e.receiver.m_values, self.dep.bs_xyz, toas[sl][:, :, FIRST_PATH],
                                                 sigma[0][sl], ue[sl], idx[sl], self.nlos)
                ext = trials.otdoa_centers(e, self.dep, ot, idx[sl]) if e.receiver.centring == "otdoa" else None
                ots.append(ot)
                dpes.append(background.submit(self._dpe, keys[sl], ts[sl], ext, batch_size, workers))
            dpes = [f.result() for f in dpes]
        return {k: np.concatenate([p[k] for p in dpes]) for k in dpes[0]} | {
            k: np.concatenate([p[k] for p in ots]) for k in ots[0]}

    #: pieces of a chunk whose OTDoA fixes and DPE overlap (speed only: every trial is computed on its own)
    OTDOA_PIECES = 4

    def _dpe(self, keys, ts, ext, batch_size: int, workers: int) -> dict:
        """The DPE fixes of trials ``ts`` (keys ``keys``); ext (T, S, J, 4) the window centres of centring "otdoa" (else None)."""
        e = self.e
        if ext is None:
            ext = np.zeros((len(keys), e.n_snr, len(e.receiver.m_values), 4))
        if e.receiver.centring == "prior":
            ext[:] = run_chunk((keys, ts), self.prior_fn, batch_size, workers=workers)[:, None, None, :]
        if self.bnb:
            return self.bnb_fixes(keys, ts, ext, workers)
        return run_chunk((keys, ts, ext), self.fn, batch_size, workers=workers)

    def bnb_fixes(self, keys, ts, ext, workers: int) -> dict:
        """The certified search's trials, one at a time: ``trials.bnb_prep_fn``, then ``trials.bnb_fix_fn``.

        Its loops run as long as the slowest trial of a batch needs, so it is not batched.

        Parameters
        ----------
        keys : PRNG keys (T, ...)
            The trials' keys (``trial_draw.trial_keys``).
        ts : int (T,)
            The trials' indices.
        ext : float (T, S, J, 4)
            The window centres [x, y, z, c δt], metres.
        workers : int
            Trials at once, in threads, the first alone so that each program is compiled once.

        Returns
        -------
        dict
            The fields of ``Results``, trials on the leading axis.
        """

        def one(i):
            trial, bs, centers, sls, starts = self.prep(keys[i], ts[i], self.window, ext[i])
            r = jax.tree.map(np.asarray, self.fix(bs, centers, sls, starts))  # WindowFix (S, J, ...)
            trial = {k: np.asarray(v) for k, v in trial.items()}
            bias, err = (np.asarray(a) for a in trials.score(r.q, trial["ue_xyz"]))
            return trial | {"est_xyz": r.q[..., :3], "est_bias_s": bias, "error_m": err,
                            "center_xyz": np.asarray(centers)[..., :3], "edge": r.edge, "gap": r.gap,
                            "certified": r.certified}

        parts = threaded(one, range(len(keys)), workers)
        return {k: np.stack([p[k] for p in parts]) for k in parts[0]}


@lru_cache(maxsize=4)
def _runner(e: Experiment) -> ChunkRunner:
    return ChunkRunner(e)


def chunk_task(experiment: bytes, start: int, stop: int, batch_size: int, version: str) -> tuple[dict, dict]:
    """Trials start … stop-1 of an experiment, computed in this process: the task ``run`` submits to a Dask cluster.

    ``run`` submits one for each missing chunk (``cluster``).  It first checks that this process runs the client's code
    (``code_version`` equal to ``version``, and no source changed since this process imported it:
    ``code_key.changed_since_import``), then unpickles the experiment and computes; a worker builds (compiles) the
    ``ChunkRunner`` of an experiment once and keeps it for the experiment's other chunks.

    Parameters
    ----------
    experiment : bytes
        The pickled ``Experiment``, pickled by the client so that a worker whose ``Experiment`` differs fails the check,
        not the unpickling.
    start, stop : int
        The chunk's trials, start … stop-1.
    batch_size : int
        Trials vmapped together.
    version : str
        The client's ``code_key.code_version``.

    Returns
    -------
    arrays : dict
        The chunk's arrays.
    origin : dict
        {"code_version": this process's, "worker": its address}, which ``cluster.gather`` checks again before it keeps
        the chunk.

    Raises
    ------
    dpe5g.simulation.cluster.OtherCode
        When this process runs other code, before any work.
    """
    mine = code_version()
    where = worker_address()
    stale = changed_since_import()
    if mine != version or stale:
        raise OtherCode(where, mine, version, stale)
    return _runner(pickle.loads(experiment))(start, stop, batch_size, workers=1), {"code_version": mine, "worker": where}


def from_supersets(supersets: list, start: int, stop: int) -> dict | None:
    """Trials start … stop-1 sliced from the first cached run at more SNRs that holds them.

    Parameters
    ----------
    supersets : list
        ``chunk_cache.snr_superset_runs``' list of (cached run, SNR index).
    start, stop : int
        The chunk's trials, start … stop-1.

    Returns
    -------
    dict or None
        The chunk's arrays; None if no run holds it (or its chunk is damaged: then set aside).
    """
    for source, snr_index in supersets:
        if source.path(start, stop).exists() and (sliced := sliced_chunk(source, start, stop, snr_index)) is not None:
            return sliced
    return None


def default_workers() -> int:
    """Batches ``run`` computes at once by default: DPE5G_WORKERS if set, else the CPUs this process may use.

    Returns
    -------
    int
        The number of workers, at least 1.

    Raises
    ------
    ValueError
        When DPE5G_WORKERS is not an integer in [1, 256].
    """
    env = os.environ.get("DPE5G_WORKERS")
    if env is not None:
        try:
            return _checks.integer("DPE5G_WORKERS", int(env), 1, 256)
        except ValueError:
            raise ValueError(f"DPE5G_WORKERS must be an integer in [1, 256], got {env!r}") from None
    return max(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1), 1)


def run(e: Experiment, cache: str | os.PathLike | None = None, progress: bool = True,
        batch_size: int | None = None, reverse: bool = False, workers: int | None = None,
        use_store: bool = True, client=None) -> Results:
    """Run (or resume, or load) an experiment.

    An experiment the results store holds (``store.stored``) is read from it, nothing computed.  Otherwise chunks
    already in the cache (``ChunkCache``) are loaded, the others computed and written as they finish; a chunk that
    another process wrote meanwhile is read, not computed again, and a chunk that a cached run of the same experiment
    at more SNRs holds is sliced from it (``chunk_cache.snr_superset_runs``).  A cached chunk that is damaged, or records
    another code version or config, is named on stderr, set aside and computed again (``chunk_cache.read_cached``).

    Parameters
    ----------
    e : Experiment
        The experiment.
    cache : str or os.PathLike or None
        The Monte Carlo cache's root folder; None: DPE5G_CACHE, else ``locations.DEFAULT_CACHE``
        (``chunk_cache.cache_root``).
    progress : bool
        Show a tqdm bar with ETA on stderr.
    batch_size : int or None
        Trials vmapped together, 1 to 4096 (memory/speed only; results do not depend on it; the certified search's
        fixes run one trial at a time); None: ``BATCH_SIZE`` of the experiment's search method.
    reverse : bool
        Compute the missing chunks last first (``warm`` does, so that a process filling the cache beside one that runs
        forward meets it in the middle instead of repeating its chunks).
    workers : int or None
        Batches of a chunk computed at once, in threads, 1 to 256 (speed only; results do not depend on it); None:
        ``default_workers()``.
    use_store : bool
        False skips the results store.
    client : distributed.Client or None
        From ``cluster.connect``: the missing chunks run as tasks on its workers (``chunk_task``), and this process
        checks that they ran its code and writes them as they arrive; None: this process computes them.

    Returns
    -------
    Results
        The experiment's per-trial results.

    Raises
    ------
    ValueError
        When ``batch_size`` or ``workers`` is out of range, ``e``'s M do not fit its deployment, or the cache folder is
        not writable.
    dpe5g.common.errors.Failure
        When a chunk computed again is damaged again when read back.
    """
    _checks.require_x64()
    batch_size = BATCH_SIZE[e.receiver.search.method] if batch_size is None else batch_size
    _checks.integer("batch_size", batch_size, 1, 4096)
    workers = default_workers() if workers is None else _checks.integer("workers", workers, 1, 256)
    e.load_deployment()  # validates m_values against the deployment before any work
    hit = stored(e) if use_store else None
    chunks = None if hit is not None else ChunkCache(e, cache).open()
    if os.environ.get("DPE5G_RUN_LOG"):  # the book build records what its chapters run (tests/book/test_warm.py)
        with open(os.environ["DPE5G_RUN_LOG"], "a") as f:
            f.write(json.dumps({"run": f"{e.run.name}-{e.config_key()}", "n_trials": e.run.n_trials,
                                "stored": hit is not None if use_store else None}) + "\n")  # None: not asked
    if hit is not None:
        return Results(e, **hit.load(e.run.n_trials))
    for _ in range(2):  # a chunk found damaged when read is set aside, so computed again once
        fill(e, chunks, chunks.missing(), batch_size, workers, client, progress, reverse, cache)
        arrays = chunks.load(stored_fields(e))
        if arrays is not None:
            return Results(e, **arrays)
    raise Failure(f"{chunks.dir}: a chunk computed again was damaged again when read back; check the disk (or "
                  f"point DPE5G_CACHE at another folder)")


def fill(e: Experiment, chunks: ChunkCache, todo: list, batch_size: int, workers: int, client, progress: bool,
         reverse: bool, cache) -> None:
    """Compute and write the chunks ``todo`` of ``e``, each where it is cheapest.

    Each comes from a cached run at more SNRs where one holds it, else is computed in this process or, with a
    ``client``, as a task on its cluster (``gather``).

    Parameters
    ----------
    e : Experiment
        The experiment.
    chunks : ChunkCache
        Its open cache, where the chunks are written.
    todo : list of (int, int)
        The chunks (start, stop) to compute.
    batch_size, workers, client, progress, reverse, cache
        As in ``run``.
    """
    bar = None
    if todo and progress:
        bar = tqdm(total=e.run.n_trials, initial=e.run.n_trials - sum(b - a for a, b in todo), desc=f"{e.run.name} trials",
                   unit="trial", file=sys.stderr, dynamic_ncols=True)
    runner = None
    supersets = snr_superset_runs(e, cache) if todo else []
    futures = {}
    try:
        for start, stop in (todo[::-1] if reverse else todo):
            if chunks.path(start, stop).exists():  # (another process may have written it since `missing`)
                pass
            elif (sliced := from_supersets(supersets, start, stop)) is not None:
                chunks.save(start, stop, sliced, computed_by="a cached run at more SNRs")
            elif client is not None:
                task = client.submit(chunk_task, pickle.dumps(e), start, stop, batch_size, chunks.code_version,
                                     pure=False)
                futures[task] = (start, stop)
                continue
            else:
                runner = runner or ChunkRunner(e)
                chunks.save(start, stop, runner(start, stop, batch_size, workers))
            if bar is not None:
                bar.update(stop - start)
        gather(futures, chunks, bar)
    finally:
        for fut in futures:
            fut.cancel()
        if bar is not None:
            bar.close()
