"""Atomic file writes shared by the figure build, the Monte Carlo cache and the CLI."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_target(path):
    """Yield a temporary path beside ``path`` (``.<name>.<pid>.…tmp``, pid the writing process) to write to; on
    success rename it to ``path``, so a reader never sees a partial file and an existing file is never left
    half-overwritten; on failure remove it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (``atomic_target``)."""
    with atomic_target(path) as tmp:
        tmp.write_bytes(data)


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
