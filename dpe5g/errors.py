"""The failures that are not bad input: a damaged file of the results store, and a Dask cluster that lost work or
runs other code.  Each carries a message that says what happened and what to do, which the command line prints as
one line (exit code 1; bad input is a ``ValueError``, exit code 2)."""

from __future__ import annotations


class Failure(RuntimeError):
    """A failure of the environment, not of the input, told in one line that names its remedy."""


class DamagedEntry(Failure):
    """A results-store entry (``store.StoredRun``) whose file cannot be read, or whose arrays do not match the
    checksum and row count its ``.json`` records.  ``dpe5g reproduce`` (``make reproduce``) rewrites it without
    reading it."""

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"results store: {path} is damaged ({reason}); run `make reproduce`, which recomputes it "
                         f"from its seeds without reading it")


class ClusterFailed(Failure):
    """The Dask cluster lost a chunk (a worker killed too often, the scheduler gone) or computed one with other
    code; the chunks finished before it are in the cache, so the same command resumes."""
