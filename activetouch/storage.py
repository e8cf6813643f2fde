"""Durable writes and cross-process locks: the one implementation the packages above share.

A write goes to a temporary file beside its target (``.<name>.XXXXXXXX.tmp``), is fsynced and
renamed over the target with ``os.replace``, then the directory is fsynced: a reader, or a
process started after a crash, finds the old content or the new, never part of either. The
temporary file comes from ``mkstemp``, so a file these functions create is private (0600).

A directory is replaced the same way (`replace_dir`): filled under a temporary name, made
durable, then swapped in by renames, the previous one put back if the swap fails.

Locks are POSIX ``flock``s on a lock file that is created if missing and never removed (a
removed lock file would let two holders lock two different inodes). The kernel drops a lock
with the process that held it, however it ended. Two open files conflict even within one
process, so threads that each call `locked` are serialised too.

Only the standard library: this is the bottom floor of the import contract (pyproject.toml).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = [
    "atomic_write_bytes",
    "atomic_write_text",
    "fsync_dir",
    "locked",
    "replace_dir",
]


def fsync_dir(path: Path) -> None:
    """Make renames in directory `path` durable. Best effort: not every platform or
    filesystem lets a directory be opened or synced, and the data itself is already synced."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Replace the file `path` with `data` so that no reader ever sees it half-written.

    The directory must exist. On any error (including KeyboardInterrupt) the target keeps
    its previous content and the temporary file is removed; the error propagates."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


def atomic_write_text(path: Path, text: str, encoding: str = "utf-8") -> None:
    """`atomic_write_bytes` of `text` encoded (UTF-8 unless told)."""
    atomic_write_bytes(path, text.encode(encoding))


def _fsync_tree(root: Path) -> None:
    for p in sorted(root.rglob("*")):
        if p.is_file() and not p.is_symlink():
            with open(p, "rb") as f:
                os.fsync(f.fileno())
        elif p.is_dir():
            fsync_dir(p)
    fsync_dir(root)


def replace_dir(dest: Path, fill: Callable[[Path], None]) -> None:
    """Replace directory `dest` (which may not exist yet) with one that `fill` writes.

    `fill` gets an empty temporary directory beside `dest` (created 0700, by ``mkdtemp``) and
    writes the files; they are fsynced here. Then the old `dest` is renamed aside, the new one
    renamed in, and the old one removed. If `fill` or the swap fails, `dest` is as it was and
    the temporary directories are gone. `dest.parent` must exist."""
    dest = Path(dest)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.tmp-", dir=dest.parent))
    old: Path | None = None
    try:
        fill(tmp)
        _fsync_tree(tmp)
        if dest.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old-", dir=dest.parent))
            os.replace(dest, old / dest.name)
        try:
            os.replace(tmp, dest)
        except BaseException:
            if old is not None:  # put the previous one back
                os.replace(old / dest.name, dest)
            raise
        fsync_dir(dest.parent)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def locked(
    lock_file: Path,
    *,
    on_wait: Callable[[str], None] | None = None,
    note: str | None = None,
) -> Iterator[None]:
    """Hold an exclusive lock on `lock_file` (its directory must exist) for the block.

    `on_wait`, if given, is called with the lock file's content when another holder makes
    this one wait (e.g. to log who holds it), before blocking. `note`, if given, is written
    into the lock file once the lock is held (e.g. this process's pid, for `on_wait`)."""
    with open(lock_file, "a+") as f:
        if on_wait is None:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        else:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                f.seek(0)
                on_wait(f.read())
                fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            if note is not None:
                # Append mode writes at the end, which is 0 once truncated.
                f.seek(0)
                f.truncate()
                f.write(note)
                f.flush()
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)
