"""Every Monte Carlo run a chapter asks for is on ``catalog.store_experiments`` (the list ``dpe5g warm`` fills the cache
with and ``dpe5g reproduce`` stores) and was read from the results store: a fresh clone's book computes no trial."""

import json
from pathlib import Path

import pytest

from dpe5g.studies import catalog

ROOT = Path(__file__).resolve().parents[2]
RUN_LOG = ROOT / ".cache" / "book-runs.jsonl"  # written by the book build (Makefile, DPE5G_RUN_LOG)


def test_the_book_reads_every_run_from_the_store():
    if not RUN_LOG.exists():
        pytest.skip(f"no book build recorded its Monte Carlo runs here ({RUN_LOG}; `make book` writes it)")
    lines = [json.loads(line) for line in RUN_LOG.read_text().splitlines() if line.strip()]
    runs = [r for r in lines if r["stored"] is not None]  # (None: a chapter computing a check on purpose)
    known = {f"{e.run.name}-{e.config_key()}": e.run.n_trials for e in catalog.store_experiments()}
    unknown = sorted({r["run"] for r in runs if r["run"] not in known})
    longer = sorted({f"{r['run']} ({r['n_trials']} > {known[r['run']]})" for r in runs
                     if r["run"] in known and r["n_trials"] > known[r["run"]]})
    assert not unknown and not longer, (
        f"catalog.store_experiments misses runs the book made: {unknown}; runs with more trials than it lists: {longer}")
    computed = sorted({r["run"] for r in runs if r["stored"] is False})
    assert not computed, f"the book computed runs the results store should hold: {computed}; run `make reproduce`"
