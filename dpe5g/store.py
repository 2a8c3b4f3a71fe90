"""The results on disk, in two tiers.

1. The results store (``figures/trials``, committed): per-trial results of every experiment the book and the
   figures read, keyed by the config (``Experiment.config_key``), each entry recording the code that computed it;
   ``verify`` recomputes a sample of its trials against today's code, ``dpe5g reproduce`` rewrites it.
2. The cache (``.cache/montecarlo``): one folder per experiment and code version (``<cache>/<name>-<key>``), one
   ``.npz`` per chunk of trials, every file written atomically (temporary file + rename), so an interrupted run
   resumes where it stopped and ends with results identical to an uninterrupted one; the chunks of a run at more
   SNRs, sliced to the SNRs asked for; and the figures' payloads (``payload_path``), keyed by the whole package.

Every file records a checksum of its arrays (``arrays_digest``), checked whenever it is read: a damaged store entry is
an ``errors.DamagedEntry`` naming the file and ``make reproduce``; a damaged cache file is named on stderr, set aside
(``*.damaged``) and computed again (``read_cached``).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import socket
import sys
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from ._io import atomic_write, remove_stale_temporaries
from .errors import DamagedEntry, Failure
from .experiment import Experiment, code_digest, code_version, numerics
from .results import Results

#: default cache directory: ``.cache/montecarlo`` next to the package (the repository root for an editable install);
#: the environment variable DPE5G_CACHE overrides it.
DEFAULT_CACHE = Path(__file__).resolve().parent.parent / ".cache" / "montecarlo"

def cache_root(cache: str | os.PathLike | None = None) -> Path:
    """The cache's root directory: the argument, else DPE5G_CACHE, else ``DEFAULT_CACHE``."""
    return Path(cache or os.environ.get("DPE5G_CACHE") or DEFAULT_CACHE)


def cache_dir(e: Experiment, cache: str | os.PathLike | None = None, version: str | None = None) -> Path:
    """The experiment's cache directory: ``<cache root>/<name>-<key>`` (``cache_root``; ``version``: the code
    version of the key, default today's, ``Experiment.key``)."""
    return cache_root(cache) / f"{e.run.name}-{e.key(version)}"


class ChunkCache:
    """One experiment's results on disk: ``cache_dir(e, cache)`` holds ``experiment.json`` (the config without the
    trial counts, and the key) and one ``.npz`` per chunk of ``chunk_trials`` trials.  Every file is written
    atomically (temporary file + rename), so a killed run leaves whole chunks and at most a stale ``*.tmp``, which
    ``open`` removes (not another live process's: two processes may fill one cache, ``warm``); ``missing`` lists the
    chunks still to compute (resume), ``load`` concatenates them all."""

    def __init__(self, e: Experiment, cache: str | os.PathLike | None = None):
        self.experiment = e
        self.code_version = code_version()  # once: a source edited during a long run does not disown its chunks
        self.dir = cache_dir(e, cache, self.code_version)
        self.chunks = [(s, min(s + e.run.chunk_trials, e.run.n_trials)) for s in range(0, e.run.n_trials, e.run.chunk_trials)]

    def path(self, start: int, stop: int) -> Path:
        return self.dir / f"trials-{start:07d}-{stop:07d}.npz"

    def open(self) -> "ChunkCache":
        """Create the directory and its metadata; remove temporary files a killed run left (their chunks are
        recomputed).  A root that is not a writable folder is a ``ValueError`` naming where it came from (the
        argument, DPE5G_CACHE or the default)."""
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
        return [c for c in self.chunks if not self.path(*c).exists()]

    def origin(self, start: int, stop: int) -> dict:
        """What chunk start … stop-1 must record (``write_cached``): the code version and config key of this
        cache's key, and its trials."""
        return {"code_version": self.code_version, "config_key": self.experiment.config_key(), "trials": [start, stop]}

    def save(self, start: int, stop: int, arrays: dict, computed_by: str | None = None) -> None:
        """Write a chunk (``write_cached``); computed_by : who computed it (default: this process, by pid and host)."""
        by = computed_by or f"process {os.getpid()} on {socket.gethostname()}"
        write_cached(self.path(start, stop), arrays, {**self.origin(start, stop), "computed_by": by})

    def read(self, start: int, stop: int) -> dict | None:
        """The chunk's arrays, None if it is missing or damaged (then set aside and named: ``read_cached``)."""
        return read_cached(self.path(start, stop), self.origin(start, stop), rows=stop - start)

    def load(self, names) -> dict | None:
        """Every chunk's arrays ``names``, concatenated; None when a chunk was damaged (set aside, so ``missing``
        lists it again)."""
        parts = [self.read(*c) for c in self.chunks]
        if any(p is None for p in parts):
            return None
        return {k: np.concatenate([p[k] for p in parts]) for k in names}


#: the ``.npz`` member of a cache file that records where its arrays come from (``write_cached``)
CACHE_META = "dpe5g_origin"


def arrays_digest(arrays: dict) -> str:
    """SHA-256 of named arrays: each name, dtype, shape and bytes, in name order.  It depends on the values only,
    not on how a file compresses them."""
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(json.dumps([k, a.dtype.str, list(a.shape)]).encode() + a.tobytes())
    return h.hexdigest()


def read_npz(path) -> dict:
    """Every array of the ``.npz`` at ``path``, read whole (so the zip's CRC-32 of each is checked); a ValueError
    saying why when the file is missing, truncated, corrupt or holds objects."""
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:  # (our handle: closed even when np.load fails)
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ValueError("the file is missing") from None
    except Exception as err:  # noqa: BLE001  (a damaged header raises anything, SyntaxError included: all damage)
        raise ValueError(f"unreadable: {type(err).__name__}: {' '.join(str(err).split()) or 'no detail'}") from None


def write_cached(path: Path, arrays: dict, origin: dict) -> None:
    """A cache file (a Monte Carlo chunk, ``bounds.link_information``'s arrays): ``arrays`` and, in the member
    ``CACHE_META``, ``origin`` (what computed them) with their ``arrays_digest``; written atomically and flushed."""
    meta = {**origin, "arrays_sha256": arrays_digest(arrays)}
    buf = io.BytesIO()
    np.savez(buf, **arrays, **{CACHE_META: np.array(json.dumps(meta, sort_keys=True))})
    atomic_write(path, buf.getvalue())


def read_cached(path: Path, origin: dict, rows: int | None = None) -> dict | None:
    """The arrays of a cache file (``write_cached``); None if it is missing.  A file that cannot be read, whose
    arrays do not match their checksum, that records another ``origin`` (another code version, config or trial
    range: a worker of another checkout, a file copied to another name) or whose arrays do not all hold ``rows``
    rows is named on stderr, set aside as ``<name>.damaged`` and None returned, so the caller computes it again."""
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
    """Move a damaged cache file to ``<name>.damaged`` (kept for a look, never read) and say so on stderr in one
    line (on a line of its own where a progress bar is drawn); returns None, what the reader then returns.  Two
    processes may read one cache: a file gone (another set it aside) or rewritten since the reader's ``seen`` stat
    (another computed it again) is left alone.  A file that cannot be moved (a read-only cache) is an
    ``errors.Failure`` saying so."""
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
    """Cached runs of ``e`` at more SNRs: experiments equal to ``e`` in every field but the name and ``snrs_db``,
    whose SNRs include all of ``e``'s, with the same key (code, data and library versions).  Trial t's draws and its
    noise (drawn once, scaled to each SNR) do not depend on the SNR list, so such a run's chunk, sliced to ``e``'s
    SNRs, is ``e``'s chunk (``tests/test_engine.py`` computes both).  Returns [(its cache, index of each of
    ``e``'s SNRs in its list)]."""
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
    """A chunk of a run at more SNRs (``source``), its (T, S, ...) arrays restricted to the SNRs ``snr_index``; None
    if that chunk is damaged (``ChunkCache.read``)."""
    z = source.read(start, stop)
    if z is None:
        return None
    return {k: v if k in PER_TRIAL_FIELDS else np.take(v, snr_index, axis=1) for k, v in z.items()}


def payload_path(fig_id: str, trials: int | None = None, cache=None) -> Path:
    """Where ``figures.compute`` keeps the payload of ``fig_id`` (with ``trials``):
    ``<cache root>/payloads/<id>-<key>.json`` beside the Monte Carlo results (``cache_root``).  The key hashes the
    figure id, the trial count, the code of every module of the package (``experiment.code_digest``: docstrings and
    comments left out), its data files, the numerical libraries' versions and the results store's content
    (``store_digest``): everything a payload is computed from, so a stored payload is exactly what computing it
    again would give, and any change of code or of the store computes it anew."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha256(json.dumps([fig_id, trials, numerics()], sort_keys=True).encode())
    for path in sorted(here.glob("*.py")):
        h.update(path.name.encode() + code_digest(path))
    for path in sorted(p for p in (here / "data").rglob("*") if p.is_file()):
        h.update(path.name.encode() + path.read_bytes())
    h.update(store_digest().encode())
    return cache_root(cache) / "payloads" / f"{fig_id}-{h.hexdigest()[:16]}.json"


def load_payload(fig_id: str, trials: int | None = None, cache=None) -> dict | None:
    """The stored payload of ``fig_id`` (``payload_path``), None when this code has not computed it, or when its
    file is damaged or fails its checksum (named on stderr and set aside as ``<name>.damaged``, so it is computed
    again)."""
    path = payload_path(fig_id, trials, cache)
    try:
        held = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:  # (never computed, or another process set it aside meanwhile)
        return None
    except ValueError as err:  # (UnicodeDecodeError included)
        return set_aside(path, f"not valid JSON: {' '.join(str(err).split())}")
    if not isinstance(held, dict) or held.get("sha256") != payload_digest(held.get("payload")):
        return set_aside(path, "its payload does not match its checksum")
    return held["payload"]


def payload_digest(payload) -> str:
    """SHA-256 of a payload's JSON (keys sorted): the checksum ``save_payload`` records."""
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def save_payload(fig_id: str, trials: int | None, payload: dict, cache=None) -> dict:
    """Store a payload (``payload_path``, written atomically) as JSON (``jsonable``) with its checksum
    (``payload_digest``, checked by ``load_payload``); returns what was stored."""
    payload = jsonable(payload)
    held = {"sha256": payload_digest(payload), "payload": payload}
    atomic_write(payload_path(fig_id, trials, cache), json.dumps(held).encode())
    return payload


def jsonable(x):
    """x with NumPy and JAX arrays and scalars turned into lists and Python numbers, recursively."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jax.Array)):
        return jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x)
    return x


# ---- the results store (tier 1) ----------------------------------------------------------------------------------

#: the committed results store; DPE5G_STORE names another folder, or "off" to compute everything (tier 2 only)
STORE_DIR = Path(__file__).resolve().parent.parent / "figures" / "trials"
def store_root() -> Path | None:
    """The results store's folder: DPE5G_STORE if set ("off": None, no store), else ``STORE_DIR``."""
    env = os.environ.get("DPE5G_STORE")
    if env == "off":
        return None
    if env and Path(env).exists() and not Path(env).is_dir():
        raise ValueError(f"DPE5G_STORE={env}: is not a folder (name a results store's folder, or 'off')")
    return Path(env) if env else STORE_DIR


def store_digest() -> str:
    """SHA-256 of the results store's files (names and bytes; "off" when there is none): what the payloads of
    ``payload_path`` read besides the code."""
    root = store_root()
    if root is None or not root.is_dir():
        return "off"
    h = hashlib.sha256()
    for path in sorted(p for p in root.iterdir() if p.suffix in (".npz", ".json")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def stored_fields(e: Experiment) -> tuple[str, ...]:
    """The fields of ``Results`` an entry of ``e`` holds: all of them (the OTDoA fields where ``e`` runs OTDoA)."""
    return Results.FIELDS + (Results.OTDOA_FIELDS if e.receiver.otdoa else ())


@dataclass(frozen=True)
class StoredRun:
    """One entry of the results store: ``<name>-<config key>.npz`` (the arrays as computed, float64 included,
    trials on the leading axis; compressed) and ``.json`` beside it (``meta``: name, config, n_trials, fields, the
    arrays' checksum ``arrays_sha256``, code version and commit)."""

    npz: Path
    meta: dict

    @property
    def n_trials(self) -> int:
        return int(self.meta["n_trials"])

    def load(self, n_trials: int | None = None, trials=None) -> dict:
        """The stored arrays of trials 0 … n_trials-1 (or of the trial indices ``trials``), after ``check``."""
        idx = slice(0, n_trials) if trials is None else np.asarray(trials)
        return {k: v[idx] for k, v in self.check().items()}

    def check(self) -> dict:
        """All the entry's arrays, read whole and checked against its ``.json``: the fields it lists, ``n_trials``
        rows each, and the checksum ``arrays_sha256`` (``arrays_digest``).  ``errors.DamagedEntry`` naming the file
        otherwise."""
        try:
            arrays = read_npz(self.npz)
        except ValueError as err:
            raise DamagedEntry(self.npz, str(err)) from None
        if sorted(arrays) != sorted(self.meta["fields"]):
            raise DamagedEntry(self.npz, f"it holds the fields {sorted(arrays)}, its .json lists "
                                         f"{sorted(self.meta['fields'])}")
        rows = {k: v.shape[0] if v.ndim else 0 for k, v in arrays.items()}
        if set(rows.values()) != {self.n_trials}:
            raise DamagedEntry(self.npz, f"its .json records {self.n_trials} trials, its arrays hold "
                                         f"{sorted(set(rows.values()))} rows")
        if arrays_digest(arrays) != self.meta["arrays_sha256"]:
            raise DamagedEntry(self.npz, "its arrays do not match the checksum its .json records")
        return arrays


#: what an entry's ``.json`` must hold (``read_entry_meta``)
ENTRY_KEYS = {"name": str, "config_key": str, "n_trials": int, "fields": dict, "arrays_sha256": str}


def read_entry_meta(meta_path: Path) -> dict:
    """An entry's ``.json``, checked to hold ``ENTRY_KEYS`` with their types and to have its ``.npz`` beside it;
    ``errors.DamagedEntry`` naming the file otherwise."""
    try:
        meta = json.loads(Path(meta_path).read_text())
    except (OSError, ValueError) as err:  # (UnicodeDecodeError included)
        raise DamagedEntry(meta_path, f"not readable JSON: {' '.join(str(err).split())}") from None
    bad = [k for k, t in ENTRY_KEYS.items() if not isinstance(meta, dict) or not isinstance(meta.get(k), t)
           or isinstance(meta.get(k), bool)]
    if bad:
        raise DamagedEntry(meta_path, f"it lacks {', '.join(bad)} or has the wrong type there")
    if not Path(meta_path).with_suffix(".npz").exists():
        raise DamagedEntry(meta_path, f"its arrays, {Path(meta_path).with_suffix('.npz').name}, are missing")
    return meta


def stored(e: Experiment, root: Path | None = None) -> StoredRun | None:
    """The store's entry for ``e`` (same config key, at least ``e.run.n_trials`` trials), None if it holds none
    or the store is off.  Trial t depends only on the config, the seed and t, so an entry of N trials serves
    any run of n ≤ N.  A damaged ``.json``, an ``.npz`` without its ``.json`` and a shorter entry that fails its
    check are an ``errors.DamagedEntry`` (the entry returned is checked when read: ``StoredRun.load``)."""
    root = store_root() if root is None else root
    if root is None or not root.is_dir():
        return None
    key = e.config_key()
    if missing_json := orphans(root, f"*-{key}.npz"):
        raise missing_json[0]
    for meta_path in sorted(root.glob(f"*-{key}.json")):
        entry = StoredRun(meta_path.with_suffix(".npz"), read_entry_meta(meta_path))
        if entry.n_trials >= e.run.n_trials:
            return entry
        entry.check()  # too short to serve: read anyway, so that a .json that understates its arrays is named
    return None


def orphans(root: Path, pattern: str) -> list[DamagedEntry]:
    """The store's ``.npz`` files matching ``pattern`` whose ``.json`` is missing, each as a ``DamagedEntry``."""
    return [DamagedEntry(npz, f"its .json, {npz.with_suffix('.json').name}, is missing")
            for npz in sorted(root.glob(pattern)) if not npz.with_suffix(".json").exists()]


def check_store(root: Path | None = None) -> list[DamagedEntry]:
    """Every entry of the store read and checked (``read_entry_meta``, ``StoredRun.check``): the damaged ones, and
    any ``.npz`` without its ``.json``."""
    root = store_root() if root is None else root
    if root is None or not root.is_dir():
        return []
    found = orphans(root, "*.npz")
    for meta_path in sorted(root.glob("*.json")):
        try:
            StoredRun(meta_path.with_suffix(".npz"), read_entry_meta(meta_path)).check()
        except DamagedEntry as err:
            found.append(err)
    return found


def write_stored(e: Experiment, arrays: dict, root: Path | None = None, code: dict | None = None) -> StoredRun:
    """Store ``e``'s results (``stored_fields``, as computed, compressed) with its config, their checksum
    (``arrays_digest``) and the code version that computed them (``code`` overrides ``{"code_version": …,
    "commit": …}``); the ``.npz`` first, then the ``.json`` that makes the entry whole, each atomically (a reader
    between the two, or after a kill there, finds a damaged entry, named as such: ``make reproduce`` again)."""
    root = store_root() if root is None else root
    if root is None:
        raise ValueError("DPE5G_STORE is 'off': there is no results store to write")
    data = {k: np.asarray(arrays[k]) for k in stored_fields(e)}
    config = e.to_dict()
    for k in ("n_trials", "chunk_trials"):
        config.pop(k)
    meta = {"name": e.run.name, "config_key": e.config_key(), "config": jsonable(config), "n_trials": e.run.n_trials,
            "fields": {k: [str(v.dtype), list(v.shape[1:])] for k, v in data.items()},
            **(code or {"code_version": code_version(), "commit": git_commit()}), "numerics": numerics(),
            "arrays_sha256": arrays_digest(data)}
    stem = f"{e.run.name}-{e.config_key()}"  # (names may hold dots: no with_suffix)
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_write(root / f"{stem}.npz", buf.getvalue())
    atomic_write(root / f"{stem}.json", (json.dumps(meta, indent=1) + "\n").encode())
    return StoredRun(root / f"{stem}.npz", meta)


def git_commit() -> str | None:
    """The checkout's commit (with "+changes" when its tracked files differ from it), None outside git."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")
