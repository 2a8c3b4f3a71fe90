"""Files on disk: atomic writes shared by the figure build, the Monte Carlo cache and the CLI, files published as one
unit (a traced city: ``publish``), checked reads of the stores' arrays (``read_npz``, ``arrays_digest``), and the
CLI's checks of an output file or folder before any work."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np


def umask() -> int:
    """The process's file mode creation mask (read without changing it where Linux shows it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


#: the longest output file name, in bytes: 255 (Linux's NAME_MAX) less what the temporary file it is first
#: written to adds (``atomic_target``: a dot, the pid, a random part and ".tmp")
MAX_NAME_BYTES = 200


def writable_dir(option: str, folder: Path, given=None) -> None:
    """Create ``folder`` if needed and check that a file can be written in it; a ValueError names ``option`` and
    the value ``given`` (default: the folder)."""
    given = folder if given is None else given
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {given}: {folder} exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise ValueError(f"{option} {given}: cannot write in {folder} ({e.strerror or e})") from None


def output_file(option: str, path: str, suffixes: tuple[str, ...], force: bool | None = None) -> Path:
    """Check an output file before any work: its suffix (one of ``suffixes``), that it is not a folder, that it does
    not exist unless ``force`` (None: overwriting is allowed), and that its folder is writable."""
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        raise ValueError(f"{option} {path}: must end in {' or '.join(suffixes)}")
    if len(p.name.encode()) > MAX_NAME_BYTES:
        raise ValueError(f"{option}: the file name is {len(p.name.encode())} bytes long; at most {MAX_NAME_BYTES} "
                         f"(the filesystem's 255, less the temporary file's additions)")
    if p.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give a file name ending in {' or '.join(suffixes)}")
    if force is False and p.exists():
        raise ValueError(f"{option} {path}: exists; pass --force to overwrite it")
    writable_dir(option, p.parent, path)
    return p


#: the temporary files ``atomic_target`` is writing in this process, which ``remove_in_flight`` deletes when the
#: command line is interrupted (it then ends at once, without unwinding)
_IN_FLIGHT: set[str] = set()


def remove_in_flight() -> None:
    """Delete this process's temporary files that are still being written (``atomic_target``), so an interrupted
    command leaves no partial file; the finished files are whole (each was moved into place in one step)."""
    for tmp in list(_IN_FLIGHT):
        try:
            os.unlink(tmp)
        except OSError:
            pass


@contextmanager
def atomic_target(path, exclusive: bool = False):
    """Yield a temporary path beside ``path`` (``.<name>.<pid>.…tmp``, pid the writing process) to write to; on
    success give it the mode a new file gets (0666 less the umask; ``mkstemp`` makes it 0600) and move it to
    ``path``, so a reader never sees a partial file and an existing file is never left half-overwritten; the file is
    flushed to disk (``fsync``) before the move and the folder after it, so a power loss leaves the old file or the
    whole new one; on failure (an interrupt included) remove it.

    exclusive : fail with ``FileExistsError`` if ``path`` exists when the file is moved there (a hard link, which
    the filesystem creates only where no file is: of two writers started at once, the second fails and the first's
    file stays); otherwise an existing file is replaced."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
    os.close(fd)
    _IN_FLIGHT.add(tmp)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~umask())
        fsync(tmp)  # the bytes on disk before the name that publishes them
        if exclusive:
            _link_new(tmp, path)
            os.unlink(tmp)
        else:
            os.replace(tmp, path)
        fsync(path.parent)  # and the rename itself
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    finally:
        _IN_FLIGHT.discard(tmp)


def fsync(path) -> None:
    """Flush the file or folder ``path`` to disk.  A file's error (EIO: the disk fault this guards against) is
    raised; a folder that cannot be opened or flushed (some filesystems refuse) is left as it is."""
    folder = os.path.isdir(path)
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        if folder:
            return
        raise
    try:
        os.fsync(fd)
    except OSError as err:
        if not (folder and err.errno in (errno.EINVAL, errno.EBADF, errno.ENOTSUP, errno.EACCES)):
            raise
    finally:
        os.close(fd)


def _link_new(tmp, path: Path) -> None:
    """Put ``tmp`` at ``path`` only if nothing is there (``FileExistsError`` otherwise): a hard link, or where the
    filesystem has none, an exclusive create of ``path`` and a copy."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError:  # no hard links here (some network and FAT filesystems)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f, open(tmp, "rb") as src:
            f.write(src.read())
            f.flush()
            os.fsync(f.fileno())


def atomic_write(path, data: bytes, exclusive: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (``atomic_target``)."""
    with atomic_target(path, exclusive) as tmp:
        tmp.write_bytes(data)


def publish(folder, unit: str, files: dict[str, bytes]) -> None:
    """Put ``files`` (file name → bytes) in ``folder`` as one unit: all of them new or all of them as they were,
    wherever the process stops (an interrupt, a kill, a power loss).

    They are written whole to a staging folder (``.<unit>.<pid>.staging``), which one rename makes the unit's pending
    publication (``.<unit>.publish``): the one step that publishes.  Its files are then moved into ``folder`` one by
    one and the pending folder removed.  A reader takes each file where ``published`` finds it, so before the rename
    it reads the old files, from it on the new ones; a publication stopped after the rename is finished by the next
    ``publish`` of the unit, or by ``finish_publish`` (``dpe5g trace`` calls it first).  This guards against a stop,
    not against two processes publishing or reading one unit at once (no lock is taken).

    Parameters
    ----------
    folder : path
        Where the files go.
    unit : str
        The unit's name (a city's), which names its staging and pending folders.
    files : dict
        The files' names (no folders) and bytes.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    finish_publish(folder, unit)
    mine = re.compile(rf"\.{re.escape(unit)}\.(\d+)\.[a-z0-9_]+\.staging")  # (not a unit "<unit>.<x>"'s)
    for old in folder.glob(f".{unit}.*.staging"):  # a killed writer's (its process gone)
        hit = mine.fullmatch(old.name)
        if hit and not _alive(int(hit.group(1))):
            shutil.rmtree(old, ignore_errors=True)
    staging = Path(tempfile.mkdtemp(dir=folder, prefix=f".{unit}.{os.getpid()}.", suffix=".staging"))
    try:
        for name, data in files.items():
            (staging / name).write_bytes(data)
            os.chmod(staging / name, 0o666 & ~umask())
            fsync(staging / name)
        os.chmod(staging, 0o777 & ~umask())
        fsync(staging)
        os.rename(staging, folder / f".{unit}.publish")
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    fsync(folder)
    finish_publish(folder, unit)


def finish_publish(folder, unit: str) -> None:
    """Move the files of ``unit``'s pending publication (``publish``), if there is one, into ``folder`` and remove it.

    Parameters
    ----------
    folder : path
        The unit's folder.
    unit : str
        The unit's name.
    """
    pending = Path(folder) / f".{unit}.publish"
    if not pending.is_dir():
        return
    for part in sorted(pending.iterdir()):
        os.replace(part, Path(folder) / part.name)
    fsync(folder)
    pending.rmdir()


def published(folder, unit: str, name: str) -> Path:
    """Where a reader finds the file ``name`` of ``unit`` (``publish``): in its pending publication while one is being
    moved into place (or was stopped on the way), else in ``folder``.

    Parameters
    ----------
    folder : path
        The unit's folder.
    unit : str
        The unit's name.
    name : str
        The file's name.

    Returns
    -------
    Path
    """
    pending = Path(folder) / f".{unit}.publish" / name
    return pending if pending.exists() else Path(folder) / name


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_stale_temporaries(directory) -> list[Path]:
    """Remove the temporary files (``atomic_target``'s ``*.tmp``) in ``directory`` that a killed writer left: those
    whose writing process is gone.  Another live process's file (two processes filling one cache) is left alone.
    Returns the paths removed."""
    gone = []
    for tmp in Path(directory).glob("*.tmp"):
        parts = tmp.name.split(".")
        pid = parts[-3] if len(parts) >= 4 else ""
        if pid.isdigit() and _alive(int(pid)):  # (a reused pid only leaves a stray file, never read)
            continue
        tmp.unlink(missing_ok=True)
        gone.append(tmp)
    return gone


def jsonable(x):
    """``x`` with NumPy and JAX arrays and scalars turned into lists and Python numbers, recursively.

    Parameters
    ----------
    x : object
        Dicts (keys made str), lists and tuples are walked; other objects are kept as they are.

    Returns
    -------
    object
        The JSON-able copy.
    """
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if hasattr(x, "shape") and hasattr(x, "dtype") and hasattr(x, "tolist"):  # NumPy and JAX arrays
        return jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x)
    return x


def arrays_digest(arrays: dict) -> str:
    """SHA-256 of named arrays: each name, dtype, shape and bytes, in name order.

    Parameters
    ----------
    arrays : dict
        The arrays by name.

    Returns
    -------
    str
        The hex digest; it depends on the values only, not on how a file compresses them.
    """
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(json.dumps([k, a.dtype.str, list(a.shape)]).encode() + a.tobytes())
    return h.hexdigest()


def read_npz(path) -> dict:
    """Every array of an ``.npz``, read whole (so the zip's CRC-32 of each is checked).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        Its arrays by name.

    Raises
    ------
    ValueError
        Saying why, when the file is missing, truncated, corrupt or holds objects.
    """
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:  # (our handle: closed even when np.load fails)
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ValueError("the file is missing") from None
    except Exception as err:  # noqa: BLE001  (a damaged header raises anything, SyntaxError included: all damage)
        raise ValueError(f"unreadable: {type(err).__name__}: {' '.join(str(err).split()) or 'no detail'}") from None
