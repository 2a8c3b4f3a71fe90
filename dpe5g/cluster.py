"""More than one machine: the Monte Carlo's chunks as tasks on a Dask cluster (``dask.distributed``).

``connect`` returns a client of an existing scheduler (``--scheduler tcp://host:8786`` or DPE5G_SCHEDULER) or of a
``LocalCluster`` of ``--workers N`` processes on this machine; ``engine.run(e, client=…)`` then submits each
missing chunk as one task (``engine.chunk_task``).  A worker imports ``dpe5g`` (float64, the XLA level and the
persistent compile cache in ``.cache/jax`` of its own checkout, or DPE5G_JAX_CACHE: point it at a shared folder so
that workers on a shared filesystem compile each program once) and compiles the programs itself: jitted functions
do not pickle, an ``Experiment`` does.  The task returns the chunk's arrays; the calling process writes them into
its cache atomically, so workers need no shared filesystem.  Trial t depends only on the seed and t, so results are
the same bits whatever the cluster (``tests/test_cluster.py``).

Each worker process runs one task at a time (``threads_per_worker=1``), the chunk's batches in that one thread;
XLA still uses the process's cores for the operations it parallelises, so on a machine of C cores start about C/2
to C workers.  Memory: a worker holds its compiled programs and one chunk (``Experiment.run.chunk_trials`` trials),
a few hundred MB (``benchmarks/bench_cluster.py`` measures it).
"""

from __future__ import annotations

import os


def connect(scheduler: str | None = None, workers: int | None = None, timeout_s: float = 20.0):
    """A ``distributed.Client``: of the scheduler at ``scheduler`` (else DPE5G_SCHEDULER), or of a new
    ``LocalCluster`` of ``workers`` single-threaded processes; None when neither is given (run in this process).
    timeout_s : how long to wait for the scheduler to answer.
    ValueError when both are given or ``workers`` is not in [1, 256]."""
    from . import _checks

    scheduler = scheduler or os.environ.get("DPE5G_SCHEDULER") or None
    if scheduler is not None and workers is not None:
        raise ValueError(f"--scheduler {scheduler} and --workers {workers} exclude each other: --workers starts a "
                         f"cluster on this machine, --scheduler (or DPE5G_SCHEDULER) uses an existing one")
    if scheduler is None and workers is None:
        return None
    from distributed import Client, LocalCluster

    if scheduler is not None:
        if not scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
            raise ValueError(f"--scheduler must be a scheduler address such as tcp://host:8786, got {scheduler!r}")
        try:
            return Client(scheduler, timeout=f"{timeout_s}s")
        except OSError as exc:
            raise ValueError(f"--scheduler {scheduler}: no Dask scheduler answers there ({exc})") from None
    workers = _checks.integer("--workers", workers, 1, 256)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster)


def close(client) -> None:
    """Close a client from ``connect`` and the ``LocalCluster`` it started, if any."""
    if client is None:
        return
    cluster = getattr(client, "cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()
