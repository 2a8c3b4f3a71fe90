"""The Monte Carlo cache (``.cache/montecarlo``, tier 2 of the results on disk; the committed tier 1 is ``store``).

One folder per experiment and code version (``<cache>/<name>-<key>``), one ``.npz`` per chunk of trials, every file
written atomically (temporary file + rename), so an interrupted run resumes where it stopped and ends with results
identical to an uninterrupted one; the chunks of a run at more SNRs, sliced to the SNRs asked for.  Every file
records a checksum of its arrays (``arrays_digest``), checked whenever it is read: a damaged cache file is named on
stderr, set aside (``*.damaged``) and computed again (``read_cached``).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import socket
import sys
from pathlib import Path

import numpy as np

from ..common._io import arrays_digest, atomic_write, read_npz, remove_stale_temporaries
from ..common.errors import Failure
from ..common.locations import DEFAULT_CACHE
from .code_key import code_version
from .experiment import Experiment

#: default cache directory: ``.cache/montecarlo`` next to the package (the repository root for an editable install);
#: the environment variable DPE5G_CACHE overrides it.

def cache_root(cache: str | os.PathLike | None = None) -> Path:
    """The cache's root directory.

    Parameters
    ----------
    cache : str, os.PathLike or None
        The root; None: DPE5G_CACHE, else ``DEFAULT_CACHE``.

    Returns
    -------
    Path
        The root (not created).
    """
    return Path(cache or os.environ.get("DPE5G_CACHE") or DEFAULT_CACHE)


def cache_dir(e: Experiment, cache: str | os.PathLike | None = None, version: str | None = None) -> Path:
    """The experiment's cache directory, ``<cache root>/<name>-<key>``.

    Parameters
    ----------
    e : Experiment
        The experiment.
    cache : str, os.PathLike or None
        The cache root (``cache_root``).
    version : str or None
        The code version of the key (``Experiment.key``); None: today's.

    Returns
    -------
    Path
        The directory (not created).
    """
    return cache_root(cache) / f"{e.run.name}-{e.key(version)}"


class ChunkCache:
    """One experiment's results on disk, one ``.npz`` per chunk of trials.

    ``cache_dir(e, cache)`` holds ``experiment.json`` (the config without the trial counts, and the key) and one
    ``.npz`` per chunk of ``chunk_trials`` trials, each written atomically, so a killed run leaves whole chunks and at
    most a stale ``*.tmp``, which ``open`` removes (not another live process's: two processes may fill one cache,
    ``warm``); ``missing`` lists the chunks still to compute (resume), ``load`` concatenates them all.

    Parameters
    ----------
    e : Experiment
        The experiment; its ``run.chunk_trials`` sets the chunks.
    cache : str, os.PathLike or None
        The cache root (``cache_root``).
    """

    def __init__(self, e: Experiment, cache: str | os.PathLike | None = None):
        self.experiment = e
        self.code_version = code_version()  # once: a source edited during a long run does not disown its chunks
        self.dir = cache_dir(e, cache, self.code_version)
        self.chunks = [(s, min(s + e.run.chunk_trials, e.run.n_trials)) for s in range(0, e.run.n_trials, e.run.chunk_trials)]

    def path(self, start: int, stop: int) -> Path:
        """The file of chunk ``start`` … ``stop``-1.

        Parameters
        ----------
        start, stop : int
            The chunk's first trial and one past its last.

        Returns
        -------
        Path
            ``trials-<start>-<stop>.npz`` in the cache directory.
        """
        return self.dir / f"trials-{start:07d}-{stop:07d}.npz"

    def open(self) -> "ChunkCache":
        """Create the directory and its metadata; remove the temporary files a killed run left (their chunks are
        recomputed).

        Returns
        -------
        ChunkCache
            This cache.

        Raises
        ------
        ValueError
            When the root is not a writable folder, naming where it came from (the argument, DPE5G_CACHE or the
            default).
        """
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.dir)
            meta = self.dir / "experiment.json"
            if not meta.exists():
                d = self.experiment.to_dict()
                d.pop("n_trials")
                d.pop("chunk_trials")
                atomic_write(meta, json.dumps({"key": self.dir.name.rsplit("-", 1)[1], "experiment": d}, indent=1,
                                              default=str).encode())
        except OSError as err:
            root = self.dir.parent
            source = (f"DPE5G_CACHE={os.environ['DPE5G_CACHE']}" if os.environ.get("DPE5G_CACHE")
                      and root == Path(os.environ["DPE5G_CACHE"]) else f"the Monte Carlo cache {root}")
            raise ValueError(f"{source}: cannot write there ({err.strerror or err}); it must be a writable "
                             f"folder") from None
        return self

    def missing(self) -> list[tuple[int, int]]:
        """The chunks still to compute (resume).

        Returns
        -------
        list of (int, int)
            The (start, stop) of each chunk whose file does not exist.
        """
        return [c for c in self.chunks if not self.path(*c).exists()]

    def origin(self, start: int, stop: int) -> dict:
        """What a chunk must record (``write_cached``).

        Parameters
        ----------
        start, stop : int
            The chunk's first trial and one past its last.

        Returns
        -------
        dict
            The code version and config key of this cache's key, and the trials ``[start, stop]``.
        """
        return {"code_version": self.code_version, "config_key": self.experiment.config_key(), "trials": [start, stop]}

    def save(self, start: int, stop: int, arrays: dict, computed_by: str | None = None) -> None:
        """Write a chunk (``write_cached``).

        Parameters
        ----------
        start, stop : int
            The chunk's first trial and one past its last.
        arrays : dict
            Its arrays by name, trials on the leading axis.
        computed_by : str or None
            Who computed it; None: this process, by pid and host.
        """
        by = computed_by or f"process {os.getpid()} on {socket.gethostname()}"
        write_cached(self.path(start, stop), arrays, {**self.origin(start, stop), "computed_by": by})

    def read(self, start: int, stop: int) -> dict | None:
        """A chunk's arrays.

        Parameters
        ----------
        start, stop : int
            The chunk's first trial and one past its last.

        Returns
        -------
        dict or None
            The arrays by name; None if the chunk is missing or damaged (then set aside and named: ``read_cached``).
        """
        return read_cached(self.path(start, stop), self.origin(start, stop), rows=stop - start)

    def load(self, names) -> dict | None:
        """Every chunk's arrays ``names``, concatenated over the trials.

        Parameters
        ----------
        names : iterable of str
            The arrays to load.

        Returns
        -------
        dict or None
            The arrays by name; None when a chunk was damaged (set aside, so ``missing`` lists it again).
        """
        parts = [self.read(*c) for c in self.chunks]
        if any(p is None for p in parts):
            return None
        return {k: np.concatenate([p[k] for p in parts]) for k in names}


#: the ``.npz`` member of a cache file that records where its arrays come from (``write_cached``)
CACHE_META = "dpe5g_origin"


def write_cached(path: Path, arrays: dict, origin: dict) -> None:
    """Write a cache file (a Monte Carlo chunk, ``bounds.link_information``'s arrays), atomically and flushed.

    Parameters
    ----------
    path : Path
        The file.
    arrays : dict
        Its arrays by name.
    origin : dict
        What computed them, stored with their ``arrays_digest`` in the member ``CACHE_META``.
    """
    meta = {**origin, "arrays_sha256": arrays_digest(arrays)}
    buf = io.BytesIO()
    np.savez(buf, **arrays, **{CACHE_META: np.array(json.dumps(meta, sort_keys=True))})
    atomic_write(path, buf.getvalue())


def read_cached(path: Path, origin: dict, rows: int | None = None) -> dict | None:
    """The arrays of a cache file (``write_cached``), checked.

    A file that cannot be read, whose arrays do not match their checksum, that records another ``origin`` (another code
    version, config or trial range: a worker of another checkout, a file copied to another name) or whose arrays do not
    all hold ``rows`` rows is named on stderr and set aside (``set_aside``), so the caller computes it again.

    Parameters
    ----------
    path : Path
        The file.
    origin : dict
        The values the file must record, by key.
    rows : int or None
        The leading length of every array; None: any.

    Returns
    -------
    dict or None
        The arrays by name; None if the file is missing or was set aside.
    """
    path = Path(path)
    try:
        seen = path.stat()  # (set_aside moves the file only if no other process rewrote it since)
    except FileNotFoundError:
        return None
    try:
        arrays = read_npz(path)
        meta = json.loads(str(arrays.pop(CACHE_META))) if CACHE_META in arrays else None
        if not isinstance(meta, dict):
            raise ValueError("it records no origin")
        if meta.get("arrays_sha256") != arrays_digest(arrays):
            raise ValueError("its arrays do not match their checksum")
        other = {k: meta.get(k) for k in origin if meta.get(k) != origin[k]}
        if other:
            raise ValueError(f"it records {other} (computed by {meta.get('computed_by', 'an unknown process')}), "
                             f"not {({k: origin[k] for k in other})}")
        if rows is not None and any(a.ndim == 0 or a.shape[0] != rows for a in arrays.values()):
            raise ValueError(f"its arrays do not hold {rows} rows each")
    except ValueError as err:
        return set_aside(path, str(err), seen)
    return arrays


def set_aside(path: Path, reason: str, seen: os.stat_result | None = None) -> None:
    """Move a damaged cache file to ``<name>.damaged`` (kept for a look, never read) and say so on stderr.

    In one line (on a line of its own where a progress bar is drawn); returns None, what the reader then returns.  Two
    processes may read one cache: a file gone (another set it aside) or rewritten since the reader's ``seen`` stat
    (another computed it again) is left alone.

    Parameters
    ----------
    path : Path
        The file.
    reason : str
        Why it is damaged, said on stderr.
    seen : os.stat_result or None
        The file's stat when the reader read it; None: move it as it is.

    Raises
    ------
    dpe5g.common.errors.Failure
        When the file cannot be moved (a read-only cache).
    """
    aside = path.with_name(path.name + ".damaged")
    try:
        now = path.stat()
        if seen is not None and (now.st_ino, now.st_mtime_ns, now.st_size) != (seen.st_ino, seen.st_mtime_ns,
                                                                               seen.st_size):
            return None
        os.replace(path, aside)
    except FileNotFoundError:
        return None
    except OSError as err:
        raise Failure(f"cache file {path} is damaged ({reason}) and cannot be set aside ({err.strerror or err}): "
                      f"delete it, or point DPE5G_CACHE at a writable folder") from None
    line = f"dpe5g: cache file {path} is damaged ({reason}); set aside as {aside.name} and computed again"
    tqdm = sys.modules.get("tqdm")
    if tqdm is not None and getattr(tqdm.tqdm, "_instances", None):
        tqdm.tqdm.write(line, file=sys.stderr)
    else:
        print(line, file=sys.stderr, flush=True)


#: chunk arrays without an SNR axis (every other array is (T, S, ...)); ``snr_superset_runs`` slices the others
PER_TRIAL_FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los")


def snr_superset_runs(e: Experiment, cache: str | os.PathLike | None = None) -> list[tuple[ChunkCache, list[int]]]:
    """Cached runs of ``e`` at more SNRs, whose chunks, sliced to ``e``'s SNRs (``sliced_chunk``), are ``e``'s.

    Such a run equals ``e`` in every field but the name and ``snrs_db``, its SNRs include all of ``e``'s and its key
    (code, data and library versions) is the same.  Trial t's draws and its noise (drawn once, scaled to each SNR) do
    not depend on the SNR list (``tests/simulation/test_engine.py`` computes both).

    Parameters
    ----------
    e : Experiment
        The experiment.
    cache : str, os.PathLike or None
        The cache root (``cache_root``).

    Returns
    -------
    list of (ChunkCache, list of int)
        Each run's cache and the index of each of ``e``'s SNRs in its list.
    """
    if e.links.snr_mode == "link_budget":
        return []
    root = cache_root(cache)
    mine = json.loads(json.dumps(e.to_dict(), default=str))
    out = []
    for meta in sorted(root.glob("*/experiment.json")) if root.is_dir() else []:
        try:
            d = json.loads(meta.read_text())["experiment"]
        except (OSError, ValueError, KeyError):
            continue  # a folder being written, or not ours: not a source
        if not isinstance(d, dict) or set(d) != set(mine) - {"n_trials", "chunk_trials"}:
            continue
        if any(d[k] != mine[k] for k in d if k not in ("name", "snrs_db")):
            continue
        snrs = [float(v) for v in d["snrs_db"]]
        if tuple(snrs) == tuple(e.links.snrs_db) or not set(e.links.snrs_db) <= set(snrs):
            continue
        other = e.replace(name=str(d["name"]), snrs_db=tuple(snrs))
        if cache_dir(other, cache) == meta.parent:  # the same code, data and versions
            out.append((ChunkCache(other, cache), [snrs.index(v) for v in e.links.snrs_db]))
    return out


def sliced_chunk(source: "ChunkCache", start: int, stop: int, snr_index: list[int]) -> dict | None:
    """A chunk of a run at more SNRs, its (T, S, ...) arrays restricted to some of its SNRs.

    Parameters
    ----------
    source : ChunkCache
        The run at more SNRs (``snr_superset_runs``).
    start, stop : int
        The chunk's first trial and one past its last.
    snr_index : list of int
        The SNRs to keep, as indices into ``source``'s list.

    Returns
    -------
    dict or None
        The arrays by name (``PER_TRIAL_FIELDS`` whole); None if that chunk is damaged (``ChunkCache.read``).
    """
    z = source.read(start, stop)
    if z is None:
        return None
    return {k: v if k in PER_TRIAL_FIELDS else np.take(v, snr_index, axis=1) for k, v in z.items()}
