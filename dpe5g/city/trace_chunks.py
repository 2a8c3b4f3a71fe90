"""A city traced in chunks: each batch of UEs of the solver cached on disk as it is traced, the chunks run in this
process or as tasks on a Dask cluster, and the city the same to the bit whatever the chunks and the workers.

The solver's table of the specular chains it has found is shared by the UEs of one call (``ray_tracer.solve_paths``),
so a UE's paths may depend on the UEs traced beside it.  The unit of work is therefore ``trace.trace_links``' own
batch, UEs b·n … (b + 1)·n − 1 with n = ``trace.ues_per_call(spec)``, whatever the chunk, the worker or the order: a
chunk is a run of whole batches (``chunk_batches`` of them, one task), and each batch is one call of the solver per
group of BSs (``trace.bs_groups``: one call for 26 BSs or fewer), seeded by ``spec.seed``.  Each call runs on one
Dr.Jit thread (``one_thread``): on Dr.Jit's pool of threads the same call's path gains vary in their last bits from run to run
(Sionna RT's street canyon, 4 BSs × 10 UEs traced four times in one process: power_db differed by up to 7.6e-6 dB),
on one thread they are the same bits every time; the parallelism is the workers'.  A batch is written to the cache
(``TRACE_CACHE/<key>/batch-<b>.npz``, atomically) as soon as it is back, so a stopped trace resumes where it stopped;
the key digests the settings, the region, the BS and UE positions, the tracing code (``trace.code_digest``), the ray
tracer's libraries and a scene file's bytes, so a cached batch is only ever reused for the very same call.

On a cluster (``common.cluster.connect``: ``--scheduler tcp://…`` or a ``LocalCluster`` of ``--workers N``) each
worker loads the scene once and traces its chunks; a task first checks that its worker runs this tracing code with
these libraries (``stack``), and the client checks it again on each chunk that comes back, as the Monte Carlo's
chunks are checked (``simulation.cluster``).  Memory: a worker holds the scene and one call's paths (about 11 GB at
50 UEs with diffuse reflection on Munich), so start as many workers as the memory holds.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..common import _checks, _io
from ..common.cluster import worker_address
from ..common.errors import ClusterFailed, Failure
from ..common.locations import TRACE_CACHE
from . import ray_tracer, trace


def stack() -> dict:
    """What a traced batch depends on beyond its inputs: the tracing code's digest, the ray tracer's libraries and the
    backend it traces on.  Chooses the backend where none is chosen yet (``ray_tracer.use_backend("auto")``).

    Returns
    -------
    dict
        {"code": ``trace.code_digest()``, ``ray_tracer.library_versions()``, and "variant": this process's Mitsuba
        variant, a value of ``ray_tracer.BACKENDS``}.
    """
    variant = ray_tracer.use_backend("auto")
    return {"code": trace.code_digest()} | ray_tracer.library_versions() | {"variant": variant}


def batch_key(spec: trace.CitySpec, region, bs_xyz, ue_xyz, n: int) -> str:
    """The cache key of a trace's batches (16 hex digits of a SHA-256).

    Parameters
    ----------
    spec : CitySpec
        The settings.
    region : tuple of 4 float
        Metres.
    bs_xyz : float (B, 3)
        BSs, metres.
    ue_xyz : float (U, 3)
        UEs, metres.
    n : int
        UEs per batch.

    Returns
    -------
    str
    """
    h = hashlib.sha256(json.dumps([spec.to_dict(), [float(v) for v in region], n, stack()], sort_keys=True).encode())
    h.update(np.ascontiguousarray(bs_xyz, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(ue_xyz, dtype=np.float64).tobytes())
    if spec.scene not in trace.SCENES:  # a scene file of one's own: its bytes (Sionna RT's are the pinned package's)
        h.update(Path(trace.scene_file(spec.scene)).read_bytes())
    return h.hexdigest()[:16]


def batch_file(folder: Path, b: int) -> Path:
    """Where batch ``b`` of a trace is cached in its ``folder``.

    Parameters
    ----------
    folder : Path
        The trace's folder in the cache (``TRACE_CACHE/<batch_key>``).
    b : int
        The batch.

    Returns
    -------
    Path
    """
    return folder / f"batch-{b:06d}.npz"


def read_batch(folder: Path, b: int) -> dict | None:
    """Batch ``b``'s links from the cache, or None when it is not there or does not read (a damaged file is removed,
    and traced again).

    Parameters
    ----------
    folder : Path
        The trace's folder in the cache.
    b : int
        The batch.

    Returns
    -------
    dict or None
        ``trace.trace_links``' arrays, "link_ue" within the batch.
    """
    try:
        with np.load(batch_file(folder, b)) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError) as exc:
        if batch_file(folder, b).exists() and not isinstance(exc, FileNotFoundError):
            batch_file(folder, b).unlink()
        return None


def write_batch(folder: Path, b: int, links: dict) -> None:
    """Write batch ``b``'s links into the cache, atomically (a stop leaves the batch whole or absent).

    Parameters
    ----------
    folder : Path
        The trace's folder in the cache (created if missing).
    b : int
        The batch.
    links : dict
        ``trace.trace_links``' arrays of the batch.
    """
    buf = io.BytesIO()
    np.savez(buf, **links)
    folder.mkdir(parents=True, exist_ok=True)
    _io.atomic_write(batch_file(folder, b), buf.getvalue())


@contextmanager
def one_thread():
    """Dr.Jit's LLVM backend on one thread while the block runs (its pool of threads restored after): the solver's
    results are then the same bits at every call.

    Yields
    ------
    None
    """
    import drjit as dr  # (Dr.Jit: loaded only to trace)

    before = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(before)


@lru_cache(maxsize=1)
def _scene(spec: trace.CitySpec):
    """The scene of ``spec``, loaded once per process (a worker traces many chunks of one city)."""
    return trace.load_scene(spec)


def trace_task(spec: trace.CitySpec, bs_xyz, ue_xyz, batches: tuple[int, ...], n: int, expected: dict):
    """Trace the batches ``batches`` (of ``n`` UEs each) of a city: the task of one chunk on a Dask worker.

    Parameters
    ----------
    spec : CitySpec
        The settings.
    bs_xyz : float (B, 3)
        Every BS, metres.
    ue_xyz : float (U, 3)
        Every UE, metres.
    batches : tuple of int
        The batches to trace.
    n : int
        UEs per batch.
    expected : dict
        The client's ``stack()``.

    Returns
    -------
    links : dict
        {b: ``trace.trace_links``' arrays of batch b, "link_ue" within the batch}.
    origin : dict
        {"stack": this process's ``stack()``, "worker": its address}.

    Raises
    ------
    ValueError
        Before any work, when this process's ``stack()`` is not ``expected``.
    """
    backend = {v: k for k, v in ray_tracer.BACKENDS.items()}.get(expected.get("variant"), "auto")
    try:
        ray_tracer.use_backend(backend)  # (the client's; a worker that cannot is refused below, naming its own)
    except Failure:
        pass
    mine, where = stack(), worker_address()
    if mine != expected:
        raise ValueError(other_stack_message(where, mine, expected))
    scene = _scene(spec)
    with one_thread():
        links = {b: trace.trace_links(scene, bs_xyz, ue_xyz[b * n:(b + 1) * n], spec, batch=n) for b in batches}
    return links, {"stack": mine, "worker": where}


def other_stack_message(worker: str, theirs: dict, ours: dict) -> str:
    """The line for a worker whose tracing code or ray-tracing libraries are not the client's.

    Parameters
    ----------
    worker : str
        The worker's address.
    theirs, ours : dict
        The worker's and the client's ``stack()``.

    Returns
    -------
    str
    """
    diff = ", ".join(f"{k} {theirs.get(k)} (here {ours.get(k)})" for k in sorted(set(theirs) | set(ours))
                     if theirs.get(k) != ours.get(k))
    return (f"Dask worker {worker} traces with other code or libraries ({diff}); none of its batches was kept: "
            f"start every worker from this checkout's environment")


def trace_city(spec: trace.CitySpec, progress: bool = True, region=None, bs_xyz=None, client=None,
               chunk_batches: int = 1, cache=None, batch: int | None = None) -> dict:
    """The city of ``spec`` as ``trace.trace_city`` traces it (the same batches, each on one thread), its batches cached
    and run in chunks: the same bits whatever ``client``, its workers and ``chunk_batches``.

    Parameters
    ----------
    spec : CitySpec
        What to trace.
    progress : bool
        Whether to show a progress bar over the UEs.
    region, bs_xyz
        As in ``trace.layout``.
    client : distributed.Client or None
        Run the chunks as tasks on its cluster (``common.cluster.connect``); None: in this process.
    chunk_batches : int
        Batches per chunk (one task), 1 to 10⁴.
    cache : str, os.PathLike or None
        The cache's root; None: ``TRACE_CACHE``.
    batch : int or None
        UEs per call of the solver; None: ``trace.ues_per_call(spec)`` (the stored cities' batches).

    Returns
    -------
    dict
        "region" float (4,) metres, "bs_xyz" (B, 3), "ue_xyz" (U, 3), and ``trace.trace_links``' arrays.

    Raises
    ------
    ValueError
        On a bad ``chunk_batches`` or ``batch``.
    dpe5g.common.errors.ClusterFailed
        In one line, when a worker runs other tracing code or libraries, or the cluster fails; the batches traced
        before stay in the cache and the same call resumes from them.
    """
    from tqdm import tqdm  # (a progress bar: loaded only to trace)

    chunk_batches = _checks.integer("chunk_batches", chunk_batches, 1, 10_000)
    scene, region, bs, ue = trace.layout(spec, region, bs_xyz)
    n = trace.ues_per_call(spec) if batch is None else _checks.integer("batch", batch, 1, 100_000)
    folder = Path(cache or TRACE_CACHE) / batch_key(spec, region, bs, ue, n)
    n_batches = math.ceil(len(ue) / n)
    parts = {b: read_batch(folder, b) for b in range(n_batches)}  # (each read once: the cached, then the traced)
    todo = [b for b, part in parts.items() if part is None]
    chunks = [tuple(todo[i:i + chunk_batches]) for i in range(0, len(todo), chunk_batches)]
    size = lambda b: min(n, len(ue) - b * n)  # noqa: E731
    with tqdm(total=len(ue), initial=len(ue) - sum(map(size, todo)), unit="UE", disable=not progress,
              desc=f"tracing {Path(spec.scene).name}: {len(bs)} BSs") as bar:
        if client is None:
            for b in todo:
                with one_thread():
                    links = trace.trace_links(scene, bs, ue[b * n:(b + 1) * n], spec, batch=n)
                write_batch(folder, b, links)
                bar.update(size(b))
        else:
            _gather(client, spec, bs, ue, chunks, n, folder, bar, size)
    parts.update({b: read_batch(folder, b) for b in todo})
    parts = [part | {"link_ue": part["link_ue"] + b * n} for b, part in sorted(parts.items())]
    links = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return {"region": np.asarray(region), "bs_xyz": bs, "ue_xyz": ue} | links


def _gather(client, spec, bs, ue, chunks, n, folder, bar, size) -> None:
    """Submit each chunk (a tuple of batches) to ``client``'s cluster and write its batches into ``folder`` as they
    come back, ``bar`` advanced by each batch's ``size``."""
    from distributed import as_completed  # (Dask: loaded only for a cluster)

    ours = stack()
    futures = {client.submit(trace_task, spec, bs, ue, c, n, ours, pure=False): c for c in chunks}
    for fut in as_completed(futures):
        try:
            links, origin = fut.result()
        except ValueError as err:
            if str(err).startswith("Dask worker"):
                raise ClusterFailed(str(err)) from None
            raise
        except Exception as err:  # noqa: BLE001  (distributed's errors, named in the message)
            done = sum(batch_file(folder, b).exists() for c in chunks for b in c)
            raise ClusterFailed(f"tracing batches {futures[fut][0]}-{futures[fut][-1]} failed on the Dask cluster "
                                f"({type(err).__name__}: {' '.join(str(err).split())}); {done} batches of this run "
                                f"are traced and kept in {folder}, and the same command resumes from them") from None
        if origin["stack"] != ours:
            raise ClusterFailed(other_stack_message(origin["worker"], origin["stack"], ours))
        for b, part in links.items():
            write_batch(folder, b, part)
            bar.update(size(b))
