"""Connecting to a Dask cluster (``dask.distributed``): an existing scheduler or a ``LocalCluster`` on this machine.

Both long computations run their chunks on it: the Monte Carlo (``simulation.cluster``, ``engine.run(e, client=…)``)
and the ray tracing of a city (``city.trace_chunks``).  ``connect`` returns a client of an existing scheduler
(``--scheduler tcp://host:8786`` or DPE5G_SCHEDULER) or of a ``LocalCluster`` of ``--workers N`` single-threaded
processes; ``close`` closes both.  Dask is imported only here and only when a cluster is asked for.
"""

from __future__ import annotations

import asyncio
import os
import re
import socket
import time
from concurrent.futures import ThreadPoolExecutor

from . import _checks


#: the scheduler addresses ``connect`` takes: TCP only (TLS, UCX and in-process addresses need set-up this package
#: does not do), a host name (Docker's service names with "_" too), IPv4 or [IPv6] address, and a port
SCHEDULER_ADDRESS = re.compile(r"tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9._\-]*):([0-9]{1,5})")


def connect(scheduler: str | None = None, workers: int | None = None, timeout_s: float = 20.0):
    """A ``distributed.Client`` of a scheduler, or of a new ``LocalCluster``; None when neither is asked for.

    Parameters
    ----------
    scheduler : str or None
        The scheduler's address ``tcp://host:port``; None (or ""): DPE5G_SCHEDULER if set.
    workers : int or None
        Start a ``LocalCluster`` of this many single-threaded processes, 1 to 256.
    timeout_s : float
        How long the whole connection may take, seconds (``check_scheduler``: TCP connect, Dask's handshake and the
        scheduler's answer).

    Returns
    -------
    distributed.Client or None
        The client; None when neither a scheduler nor ``workers`` is given (run in this process).

    Raises
    ------
    ValueError
        When both are given, ``workers`` is not in [1, 256], the address is not ``tcp://host:port`` or no Dask
        scheduler answers there in time.
    """

    source = "--scheduler"
    if not scheduler and os.environ.get("DPE5G_SCHEDULER"):
        scheduler, source = os.environ["DPE5G_SCHEDULER"], "DPE5G_SCHEDULER"
    scheduler = scheduler or None
    if scheduler is not None and workers is not None:
        raise ValueError(f"{source} {scheduler} and --workers {workers} exclude each other: --workers starts a "
                         f"cluster on this machine, --scheduler (or DPE5G_SCHEDULER) uses an existing one")
    if scheduler is None and workers is None:
        return None
    from distributed import Client  # (Dask: loaded only for a cluster)

    if scheduler is not None:
        left = check_scheduler(scheduler, timeout_s, source)
        try:
            return Client(scheduler, timeout=f"{max(left, 1.0)}s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"{source} {scheduler}: no Dask scheduler answers there ({exc})") from None
    return Client(local_cluster(_checks.integer("--workers", workers, 1, 256)))


def local_cluster(n_workers: int, **options):
    """A ``distributed.LocalCluster`` of single-threaded worker processes with no dashboard.

    Its scheduler's HTTP server listens on a free port of 127.0.0.1 (distributed binds it to 8787 even without a
    dashboard, so two clusters on one machine, or a real scheduler's dashboard there, collided).

    Parameters
    ----------
    n_workers : int
        Worker processes.
    **options
        Further ``LocalCluster`` options (they override these).

    Returns
    -------
    distributed.LocalCluster
        The cluster, started.
    """
    from distributed import LocalCluster  # (Dask: loaded only for a cluster)

    return LocalCluster(**{"n_workers": n_workers, "threads_per_worker": 1, "processes": True,
                           "dashboard_address": None,
                           "scheduler_kwargs": {"dashboard": False, "dashboard_address": "127.0.0.1:0"}, **options})


def check_scheduler(address: str, timeout_s: float, source: str = "--scheduler") -> float:
    """Check that a Dask scheduler answers at ``address`` within ``timeout_s`` seconds in all.

    The TCP connect, Dask's handshake and its answer to an "identity" request run under one deadline:
    ``distributed.Client``'s own timeout covers the connect only, so a port where something else listens (a web server,
    the dashboard's 8787) would hang it for good.  Runs in a thread of its own, so it works inside a running event loop
    (Jupyter) too.

    Parameters
    ----------
    address : str
        ``tcp://host:port`` (``SCHEDULER_ADDRESS``).
    timeout_s : float
        The deadline, seconds.
    source : str
        Where the address came from, for the message ("--scheduler" or "DPE5G_SCHEDULER").

    Returns
    -------
    float
        The seconds left of ``timeout_s``.

    Raises
    ------
    ValueError
        Naming ``source`` and what was found, when the address is malformed or no Dask scheduler answers there in time.
    """
    from distributed.comm import connect as comm_connect  # (Dask: loaded only for a cluster)

    m = SCHEDULER_ADDRESS.fullmatch(address)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise ValueError(f"{source} must be a Dask scheduler address tcp://host:port (port 1-65535; the "
                         f"scheduler's default is 8786; tls://, ucx:// and inproc:// are not supported), got "
                         f"{address!r}")
    deadline = time.monotonic() + timeout_s
    left = lambda: max(deadline - time.monotonic(), 0.001)  # noqa: E731
    try:  # first a plain TCP connect: distributed's own retries a refused connection until its timeout
        socket.create_connection((m.group(1).strip("[]"), int(m.group(2))), timeout=left()).close()
    except OSError as exc:
        raise ValueError(f"{source} {address}: no Dask scheduler answers there (nothing accepts a connection: "
                         f"{' '.join(str(exc.strerror or exc).split())})") from None

    async def identity():
        comm = await comm_connect(address, timeout=left())
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    async def within():
        return await asyncio.wait_for(identity(), left())

    try:
        with ThreadPoolExecutor(1) as pool:
            answer = pool.submit(asyncio.run, within()).result()
    except (TimeoutError, asyncio.TimeoutError):
        raise ValueError(f"{source} {address}: no Dask scheduler answered within {timeout_s:g} s (something may "
                         f"listen there that is not one: the dashboard is on 8787, the scheduler on 8786 by "
                         f"default)") from None
    except OSError as exc:
        raise ValueError(f"{source} {address}: no Dask scheduler answers there "
                         f"({' '.join(str(exc).split())})") from None
    except Exception as exc:  # noqa: BLE001  (a peer that answers, but not in Dask's protocol)
        raise ValueError(f"{source} {address}: what answers there is not a Dask scheduler "
                         f"({type(exc).__name__})") from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        raise ValueError(f"{source} {address}: what answers there is not a Dask scheduler (it said "
                         f"{str(answer)[:80]!r})")
    return left()


def close(client) -> None:
    """Close a client from ``connect`` and the ``LocalCluster`` it started, if any.

    Parameters
    ----------
    client : distributed.Client or None
        The client; None does nothing.
    """
    if client is None:
        return
    cluster = getattr(client, "cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()


def worker_address() -> str:
    """The address of the Dask worker running this call.

    Returns
    -------
    str
        The address; "this process" outside a worker.
    """
    try:
        from distributed import get_worker  # (Dask: loaded only for a cluster)

        return get_worker().address
    except (ImportError, ValueError):
        return "this process"
