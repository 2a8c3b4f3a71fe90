"""The Monte Carlo on a Dask cluster (``cluster``, ``engine.run(client=…)``): the same bits as one process, and
clear errors for bad cluster options."""

import numpy as np
import pytest

from dpe5g.receivers import search_config
from dpe5g.common import cluster as connection
from dpe5g.simulation import chunk_cache, cluster, code_key, engine, experiment, store

#: the truth-centred grid search: the quickest engine to compile, in each worker as in this process
SMALL = dict(n_trials=6, chunk_trials=2, snrs_db=(10.0, 30.0), m_values=(4, 6),
             search=search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=3.0))


def test_a_local_cluster_gives_the_results_of_one_process(tmp_path):
    e = experiment.Experiment.build(name="dask", **SMALL)
    one = engine.run(e, cache=tmp_path / "one", progress=False, use_store=False)
    client = connection.connect(workers=2)
    try:
        assert len(client.scheduler_info()["workers"]) == 2
        two = engine.run(e, cache=tmp_path / "two", progress=False, use_store=False, client=client)
    finally:
        connection.close(client)
    assert sorted(p.name for p in chunk_cache.cache_dir(e, tmp_path / "two").glob("*.npz")) == [
        "trials-0000000-0000002.npz", "trials-0000002-0000004.npz", "trials-0000004-0000006.npz"]
    for k in store.stored_fields(e):
        np.testing.assert_array_equal(getattr(one, k), getattr(two, k), err_msg=k)


def test_bad_cluster_options_are_named(monkeypatch):
    monkeypatch.delenv("DPE5G_SCHEDULER", raising=False)
    assert connection.connect() is None
    with pytest.raises(ValueError, match="--scheduler .* and --workers 2 exclude each other"):
        connection.connect("tcp://127.0.0.1:1", 2)
    with pytest.raises(ValueError, match="--workers must be"):
        connection.connect(workers=0)
    for address in ("localhost:8786", "tls://127.0.0.1:8786", "ucx://127.0.0.1:8786", "inproc://127.0.0.1/1/2",
                    "tcp://127.0.0.1", "tcp://127.0.0.1:0", "tcp://127.0.0.1:70000", "tcp://:8786", "tcp://a b:1"):
        with pytest.raises(ValueError, match="--scheduler must be a Dask scheduler address tcp://host:port"):
            connection.connect(address)
    monkeypatch.setenv("DPE5G_SCHEDULER", "tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match="DPE5G_SCHEDULER tcp://127.0.0.1:1: no Dask scheduler answers there"):
        connection.connect(timeout_s=1.0)
    monkeypatch.setenv("DPE5G_SCHEDULER", "ucx://127.0.0.1:8786")
    with pytest.raises(ValueError, match="DPE5G_SCHEDULER must be a Dask scheduler address"):
        connection.connect()


def test_a_port_where_no_scheduler_speaks_is_named_within_the_timeout(monkeypatch):
    """An HTTP server (or the dashboard's 8787) accepts the TCP connection and never answers Dask's handshake:
    distributed's own timeout covers the connect only and hung for good; ``check_scheduler`` covers it all."""
    import http.server
    import threading
    import time

    monkeypatch.delenv("DPE5G_SCHEDULER", raising=False)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        t0 = time.monotonic()
        with pytest.raises(ValueError, match="no Dask scheduler answered within 1 s .*8786"):
            connection.connect(f"tcp://127.0.0.1:{server.server_address[1]}", timeout_s=1.0)
        assert time.monotonic() - t0 < 10
    finally:
        server.shutdown()
        server.server_close()


def test_a_worker_running_other_code_is_refused(tmp_path):
    """A worker started from another checkout (here a copy of the package with one function added to the grid
    search's config, so another ``code_version``) refuses every chunk before any work, the run ends in one line
    naming it, and no chunk of it is kept."""
    import os
    import shutil
    import subprocess
    import sys

    from dpe5g.common.errors import ClusterFailed

    other = tmp_path / "other"
    shutil.copytree(code_key.PACKAGE, other / "dpe5g", ignore=shutil.ignore_patterns("__pycache__"))
    sc = other / "dpe5g" / "receivers" / "search_config.py"
    sc.write_text(sc.read_text() + "\n\ndef levels_of_another_checkout():\n    return 3\n")
    e = experiment.Experiment.build(name="dask", **SMALL)
    with connection.local_cluster(0, processes=False, protocol="tcp") as lc, connection.connect(lc.scheduler_address) as client:
        env = {**os.environ, "PYTHONPATH": str(other), "DPE5G_JAX_CACHE": "off"}
        worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", lc.scheduler_address,
                                   "--nthreads", "1", "--no-nanny", "--no-dashboard"], cwd=other, env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            client.wait_for_workers(1, timeout=120)
            address = next(iter(client.scheduler_info()["workers"]))
            with pytest.raises(ClusterFailed, match=f"Dask worker {address} runs other dpe5g code .*none kept"):
                engine.run(e, cache=tmp_path / "cache", progress=False, use_store=False, client=client)
        finally:
            worker.kill()
            worker.wait()
    assert not list(chunk_cache.cache_dir(e, tmp_path / "cache").glob("*.npz"))


def test_a_worker_killed_repeatedly_is_one_line(tmp_path):
    """distributed's KilledWorker becomes one ``ClusterFailed`` line saying what happened and that the finished
    chunks are kept (``cluster.gather``; a lost scheduler: the command-line test below)."""
    import os

    import dask
    from distributed import Client

    from dpe5g.common.errors import ClusterFailed

    chunks = chunk_cache.ChunkCache(experiment.Experiment.build(name="dask", **SMALL), tmp_path).open()
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with connection.local_cluster(1) as lc, Client(lc) as client:
            with pytest.raises(ClusterFailed, match="trials 0-1 died repeatedly .*0 of the run's 3 chunks are "
                                                    "finished and kept in the cache"):
                cluster.gather({client.submit(os._exit, 1, pure=False): (0, 2)}, chunks)


def test_a_worker_whose_files_changed_after_it_imported_them_refuses(monkeypatch):
    """A worker left running across a `git pull` has this checkout's files but older code in memory: its sources
    changed after it imported dpe5g, and it refuses the chunk as a worker of other code does."""
    import pickle

    import dpe5g

    e = experiment.Experiment.build(name="dask", **SMALL)
    monkeypatch.setattr(dpe5g, "IMPORTED_AT_NS", 0)  # every source file is newer than the import
    with pytest.raises(cluster.OtherCode) as err:
        engine.chunk_task(pickle.dumps(e), 0, 2, 2, code_key.code_version())
    assert "simulation/engine.py" in err.value.stale
    assert "restart the worker" in cluster.other_code_message(err.value.worker, err.value.theirs, "x", err.value.stale)


def test_a_lost_scheduler_is_one_line_from_the_command_line(tmp_path, monkeypatch, capfd):
    """The command line's stderr holds its one line, not also distributed's client traceback of its reconnect;
    and the scheduler check works inside a running event loop (Jupyter's)."""
    import asyncio
    import threading
    import time

    from dpe5g.cli import main as cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path / "cache"))
    lc = connection.local_cluster(1, protocol="tcp")

    async def in_a_loop():
        return connection.check_scheduler(lc.scheduler_address, 10.0)

    assert asyncio.run(in_a_loop()) > 0

    def lose_the_scheduler_after_the_first_chunk():  # (a run of 20000 trials cannot end before)
        while not list((tmp_path / "cache").glob("run-*/trials-*.npz")):
            time.sleep(0.01)
        lc.close()

    threading.Thread(target=lose_the_scheduler_after_the_first_chunk, daemon=True).start()
    code = cli.main(["run", "--trials", "20000", "--snr", "20", "--m", "6", "--centring", "truth", "--out", "r.csv",
                     "--scheduler", lc.scheduler_address])
    err = capfd.readouterr().err
    ours = [ln for ln in err.splitlines() if ln.startswith("dpe5g")]
    assert code == 1 and len(ours) == 1 and "connection to the Dask scheduler was lost" in ours[0], err
    assert "distributed.client" not in err and "Traceback" not in err, err
    assert not (tmp_path / "r.csv").exists()
