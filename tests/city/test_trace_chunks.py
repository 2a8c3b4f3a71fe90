"""A city traced in chunks (``city.trace_chunks``): the same bits in this process, on one Dask worker and on two,
whatever the chunk size; a stopped trace resumes from its cached batches; a worker with another tracing stack is
refused in one line.  Sionna RT's street canyon, 4 BSs × 10 UEs in batches of 3 (4 calls of the solver)."""

import numpy as np
import pytest

from dpe5g.city import trace, trace_chunks
from dpe5g.common import cluster
from dpe5g.common.errors import ClusterFailed


@pytest.fixture(scope="module")
def spec():
    import sionna.rt as rt

    return trace.CitySpec(scene=rt.scene.simple_street_canyon, side_m=60.0, n_bs=4, n_ue=10, samples_per_src=10000,
                          max_depth=2, scattering_coefficient=0.0, diffuse_reflection=False)


def same(a: dict, b: dict) -> list[str]:
    """The keys whose arrays are not the same bits."""
    return [k for k in sorted(set(a) | set(b)) if k not in a or k not in b or not np.array_equal(a[k], b[k])]


def test_the_city_is_the_same_bits_on_one_worker_or_two_in_any_chunks(spec, tmp_path):
    here = trace_chunks.trace_city(spec, progress=False, cache=tmp_path / "here", batch=3)
    assert len(here["link_ue"]) > 0 and set(here["link_ue"]) == set(range(10))
    for workers, chunk in ((1, 1), (2, 2)):
        client = cluster.connect(workers=workers)
        try:
            there = trace_chunks.trace_city(spec, progress=False, cache=tmp_path / f"w{workers}", batch=3,
                                            client=client, chunk_batches=chunk)
        finally:
            cluster.close(client)
        assert not same(here, there), (workers, chunk, same(here, there))
    # the batches are trace_links' own: the same UEs in each call of the solver, on one thread
    scene, _, bs, ue = trace.layout(spec)
    with trace_chunks.one_thread():
        assert not same({k: here[k] for k in here if k not in ("region", "bs_xyz", "ue_xyz")},
                        trace.trace_links(scene, bs, ue, spec, batch=3))


def test_a_stopped_trace_resumes_from_its_batches(spec, tmp_path, monkeypatch):
    whole = trace_chunks.trace_city(spec, progress=False, cache=tmp_path, batch=3)
    (folder,) = tmp_path.iterdir()
    assert sorted(p.name for p in folder.iterdir()) == [f"batch-{b:06d}.npz" for b in range(4)]
    trace_chunks.batch_file(folder, 2).unlink()  # stopped before batch 2 was written
    trace_chunks.batch_file(folder, 3).write_bytes(b"cut short")  # a damaged file is traced again
    written = []
    real = trace_chunks.write_batch
    monkeypatch.setattr(trace_chunks, "write_batch", lambda f, b, links: written.append(b) or real(f, b, links))
    again = trace_chunks.trace_city(spec, progress=False, cache=tmp_path, batch=3)
    assert written == [2, 3] and not same(whole, again)  # batches 2 and 3 traced again, 0 and 1 read


def test_a_worker_with_another_stack_is_refused_before_any_work(spec):
    ours = trace_chunks.stack()
    with pytest.raises(ValueError, match=r"Dask worker this process traces with other code or libraries \(code "):
        trace_chunks.trace_task(spec, np.zeros((4, 3)), np.zeros((10, 3)), (0,), 3, ours | {"code": "0" * 16})
    with pytest.raises(ValueError, match="chunk_batches must be an integer in"):
        trace_chunks.trace_city(spec, progress=False, chunk_batches=0)
    assert issubclass(ClusterFailed, Exception)


def test_more_bss_than_one_call_takes_are_traced_in_groups_and_merged(spec, monkeypatch):
    """``trace.trace_links`` traces each group of ``trace.bs_groups`` in a call of its own and merges the links in order
    of UE, then BS: the same bits as the groups traced on their own (here groups of 2 of the street canyon's 4 BSs)."""
    assert trace.bs_groups(26) == [range(26)] and trace.bs_groups(27) == [range(26), range(26, 27)]
    assert trace.bs_groups(104) == [range(b, b + 26) for b in range(0, 104, 26)]
    scene, _, bs, ue = trace.layout(spec)
    with trace_chunks.one_thread():
        halves = [trace.trace_links(scene, bs[g], ue, spec, batch=5) for g in (slice(0, 2), slice(2, 4))]
        monkeypatch.setattr(trace, "bs_groups", lambda n: [range(0, 2), range(2, n)])
        grouped = trace.trace_links(scene, bs, ue, spec, batch=5)
    halves[1]["link_bs"] = halves[1]["link_bs"] + 2
    merged = {k: np.concatenate([h[k] for h in halves]) for k in halves[0]}
    order = np.lexsort((merged["link_bs"], merged["link_ue"]))
    assert not same(grouped, {k: v[order] for k, v in merged.items()})
    assert np.all(np.diff(grouped["link_ue"].astype(int) * 4 + grouped["link_bs"]) > 0)  # by UE, then BS
    assert grouped["link_bs"].dtype == np.int16 and grouped["link_ue"].dtype == np.int32


def test_the_tracing_code_digest_is_read_once_per_process(monkeypatch):
    """A process traces with the code it imported: files edited under a running trace (``inspect.getsource`` reads
    them) leave its digest, and so its cache keys and its cities' records, as they were."""
    first = trace.code_digest()
    monkeypatch.setattr(trace.inspect, "getsource", lambda obj: "def edited():\n    return 1\n")
    assert trace.code_digest() == first
