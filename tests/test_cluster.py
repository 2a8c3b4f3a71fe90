"""The Monte Carlo on a Dask cluster (``cluster``, ``engine.run(client=…)``): the same bits as one process, and
clear errors for bad cluster options."""

import numpy as np
import pytest

from dpe5g import cluster, engine, experiment, search_config, store

#: the truth-centred grid search: the quickest engine to compile, in each worker as in this process
SMALL = dict(n_trials=6, chunk_trials=2, snrs_db=(10.0, 30.0), m_values=(4, 6),
             search=search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=3.0))


def test_a_local_cluster_gives_the_results_of_one_process(tmp_path):
    e = experiment.Experiment.build(name="dask", **SMALL)
    one = engine.run(e, cache=tmp_path / "one", progress=False, use_store=False)
    client = cluster.connect(workers=2)
    try:
        assert len(client.scheduler_info()["workers"]) == 2
        two = engine.run(e, cache=tmp_path / "two", progress=False, use_store=False, client=client)
    finally:
        cluster.close(client)
    assert sorted(p.name for p in store.cache_dir(e, tmp_path / "two").glob("*.npz")) == [
        "trials-0000000-0000002.npz", "trials-0000002-0000004.npz", "trials-0000004-0000006.npz"]
    for k in store.stored_fields(e):
        np.testing.assert_array_equal(getattr(one, k), getattr(two, k), err_msg=k)


def test_bad_cluster_options_are_named(monkeypatch):
    monkeypatch.delenv("DPE5G_SCHEDULER", raising=False)
    assert cluster.connect() is None
    with pytest.raises(ValueError, match="--scheduler .* and --workers 2 exclude each other"):
        cluster.connect("tcp://127.0.0.1:1", 2)
    with pytest.raises(ValueError, match="--workers must be"):
        cluster.connect(workers=0)
    for address in ("localhost:8786", "tls://127.0.0.1:8786", "ucx://127.0.0.1:8786", "inproc://127.0.0.1/1/2",
                    "tcp://127.0.0.1", "tcp://127.0.0.1:0", "tcp://127.0.0.1:70000", "tcp://:8786", "tcp://a b:1"):
        with pytest.raises(ValueError, match="--scheduler must be a Dask scheduler address tcp://host:port"):
            cluster.connect(address)
    monkeypatch.setenv("DPE5G_SCHEDULER", "tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match="DPE5G_SCHEDULER tcp://127.0.0.1:1: no Dask scheduler answers there"):
        cluster.connect(timeout_s=1.0)
    monkeypatch.setenv("DPE5G_SCHEDULER", "ucx://127.0.0.1:8786")
    with pytest.raises(ValueError, match="DPE5G_SCHEDULER must be a Dask scheduler address"):
        cluster.connect()


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
            cluster.connect(f"tcp://127.0.0.1:{server.server_address[1]}", timeout_s=1.0)
        assert time.monotonic() - t0 < 10
    finally:
        server.shutdown()
        server.server_close()
