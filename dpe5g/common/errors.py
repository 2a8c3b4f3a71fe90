"""The failures that are not bad input: a damaged results-store file, a Dask cluster that lost work or ran other code.

Each carries a message that says what happened and what to do, which the command line prints as one line (exit
code 1; bad input is a ``ValueError``, exit code 2).
"""

from __future__ import annotations


class Failure(RuntimeError):
    """A failure of the environment, not of the input, told in one line that names its remedy."""


class DamagedEntry(Failure):
    """A results-store entry (``store.StoredRun``) whose file cannot be read, or whose arrays do not match its record.

    The record is the checksum and row count its ``.json`` holds.  ``dpe5g reproduce`` (``make reproduce``) rewrites
    the entry without reading it.

    Parameters
    ----------
    path : str or os.PathLike
        The damaged file; kept as the attribute ``path`` (a str).
    reason : str
        What is wrong with it, in a few words; kept as the attribute ``reason``.
    """

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"results store: {path} is damaged ({reason}); run `make reproduce`, which recomputes it "
                         f"from its seeds without reading it")


class ClusterFailed(Failure):
    """The Dask cluster lost a chunk (a worker killed too often, the scheduler gone) or computed one with other code.

    The chunks finished before it are in the cache, so the same command resumes.
    """
