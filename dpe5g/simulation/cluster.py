"""More than one machine: the Monte Carlo's chunks as tasks on a Dask cluster (``dask.distributed``).

``common.cluster.connect`` returns a client of an existing scheduler (``--scheduler tcp://host:8786`` or
DPE5G_SCHEDULER) or of a ``LocalCluster`` of ``--workers N`` processes on this machine; ``engine.run(e, client=…)`` then submits each
missing chunk as one task (``engine.chunk_task``).  A worker imports ``dpe5g`` (float64, the XLA level and the
persistent compile cache in ``.cache/jax`` of its own checkout, or DPE5G_JAX_CACHE: point it at a shared folder so
that workers on a shared filesystem compile each program once) and compiles the programs itself: jitted functions
do not pickle, an ``Experiment`` does.  The task returns the chunk's arrays; the calling process writes them into
its cache atomically, so workers need no shared filesystem.  Trial t depends only on the seed and t, so results are
the same bits whatever the cluster (``tests/simulation/test_cluster.py``).

A worker must run the client's code: each task first compares its process's ``code_key.code_version`` with the
client's and refuses before any work (``OtherCode``), and the client checks the version each chunk comes back with
(``gather``): a worker started from another checkout, or with other library versions, ends the run in one line
naming it, and none of its chunks is kept.  A worker killed too often or a lost scheduler ends it in one line too
(``errors.ClusterFailed``); the chunks finished before are in the cache, and the same command resumes.

Each worker process runs one task at a time (``threads_per_worker=1``), the chunk's batches in that one thread;
XLA still uses the process's cores for the operations it parallelises, so on a machine of C cores start about C/2
to C workers.  Memory: a worker holds its compiled programs and one chunk (``Experiment.run.chunk_trials`` trials),
a few hundred MB (``benchmarks/bench_cluster.py`` measures it).
"""

from __future__ import annotations

from ..common.errors import ClusterFailed


class OtherCode(Exception):
    """Raised by ``engine.chunk_task``, before any work, on a worker that does not run the client's code.

    The worker's code version is not the client's, or its sources changed after it imported them.  It travels back to
    the client, which ``gather`` turns into an ``errors.ClusterFailed``.  The arguments are kept as attributes of the
    same names.

    Parameters
    ----------
    worker : str
        The worker's address.
    theirs, ours : str
        The worker's and the client's code versions.
    stale : tuple of str
        The names of the sources that changed after the worker imported them.
    """

    def __init__(self, worker: str, theirs: str, ours: str, stale: tuple[str, ...] = ()):
        super().__init__(worker, theirs, ours, tuple(stale))
        self.worker, self.theirs, self.ours, self.stale = worker, theirs, ours, tuple(stale)


def gather(futures: dict, chunks, bar=None) -> None:
    """Write each chunk a Dask task returns into ``chunks`` as it arrives, after checking that its worker ran this code.

    Parameters
    ----------
    futures : dict
        {future of ``engine.chunk_task``: (start, stop)}.
    chunks : chunk_cache.ChunkCache
        The run's cache.
    bar : tqdm or None
        Progress bar updated per chunk.

    Raises
    ------
    dpe5g.common.errors.ClusterFailed
        Saying so in one line, on a chunk from other code, a worker killed too often or a lost scheduler; the chunks
        written before it stay in the cache.
    """
    if not futures:
        return
    from distributed import as_completed  # (Dask: loaded only for a cluster)

    mine = chunks.code_version
    for fut in as_completed(futures):
        start, stop = futures[fut]
        try:
            arrays, origin = fut.result()
        except OtherCode as err:
            raise ClusterFailed(other_code_message(err.worker, err.theirs, mine, err.stale)) from None
        except Exception as err:  # noqa: BLE001  (distributed's errors, named in the message)
            raise ClusterFailed(cluster_lost_message(err, start, stop, chunks)) from None
        if origin["code_version"] != mine:
            raise ClusterFailed(other_code_message(origin["worker"], origin["code_version"], mine))
        chunks.save(start, stop, arrays, computed_by=f"Dask worker {origin['worker']}")
        if bar is not None:
            bar.update(stop - start)


def other_code_message(worker: str, theirs: str, mine: str, stale: tuple[str, ...] = ()) -> str:
    """``gather``'s line for a worker that runs other code (or code older than its files).

    Parameters
    ----------
    worker : str
        The worker's address.
    theirs, mine : str
        The worker's and this process's code versions.
    stale : tuple of str
        The sources that changed after the worker imported them (empty: another code version).

    Returns
    -------
    str
        The line.
    """
    if stale:
        return (f"Dask worker {worker} runs dpe5g code older than its files ({', '.join(stale)} changed after it "
                f"imported them); its chunks were refused, none kept: restart the worker")
    return (f"Dask worker {worker} runs other dpe5g code (code version {theirs}, this checkout's {mine}: another "
            f"checkout, or other library versions); its chunks were refused, none kept: start every worker from "
            f"this checkout's environment")


def cluster_lost_message(err: Exception, start: int, stop: int, chunks) -> str:
    """``gather``'s line for a task that failed on the cluster: what happened, and that finished chunks are kept.

    Parameters
    ----------
    err : Exception
        The task's error.
    start, stop : int
        The chunk's trials, start … stop-1.
    chunks : chunk_cache.ChunkCache
        The run's cache.

    Returns
    -------
    str
        The line.
    """
    kind = type(err).__name__
    if kind == "KilledWorker":
        what = (f"the workers running trials {start}-{stop - 1} died repeatedly (Dask gave up after "
                f"distributed.scheduler.allowed-failures; out of memory?)")
    elif kind in ("CancelledError", "FutureCancelledError", "CommClosedError", "TimeoutError", "OSError",
                  "ConnectionError", "StreamClosedError"):
        what = f"the connection to the Dask scheduler was lost ({kind}) while trials {start}-{stop - 1} ran"
    else:
        hint = " (a worker of an older dpe5g checkout?)" if kind == "TypeError" and "chunk_task" in str(err) else ""
        what = f"trials {start}-{stop - 1} failed on a Dask worker: {kind}: {' '.join(str(err).split())}{hint}"
    done = len(chunks.chunks) - len(chunks.missing())
    return (f"{what}; {done} of the run's {len(chunks.chunks)} chunks are finished and kept in the cache "
            f"({chunks.dir}), and the same command resumes from them")
