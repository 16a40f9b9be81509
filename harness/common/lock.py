"""One process per run folder: an exclusive lock held for the whole run.

``eval``, ``collect``, ``replay`` and their ``--resume`` (and ``report``, ``train``,
``teacher``, ``reproduce``, ``nets build`` in their output folder) hold ``run.lock`` in
the run folder while they run: a second command on the same folder is refused at once (``BadInput`` naming the
holder's process id), so two runs never write into one folder, and a ``--resume`` never
runs beside the run it would finish.

The lock is the kernel's (``flock`` on the open lock file), not the file's presence: it is
released when its process ends, however it ends (kill -9, power loss), so a lock file left
by a dead process is simply taken over. The file holds the holder's pid (for the message)
and is removed when the run ends. On a file system without ``flock`` the pid decides: a
lock whose process is gone is taken over.

The lock file, and every file a run appends to, is opened without following a symbolic
link (``open_nofollow``): a link placed there is refused, its target left alone. A run
also checks before each write that its folder is still the one it locked
(``check_folder``): a folder removed and made again under the same path meanwhile stops the
old run instead of mixing its files with the new one's.

Locking creates the folder (and the missing folders above it); if the command then stops
before writing anything there (a refused resume, an unwritable results path), those
folders are removed again, so bad input leaves nothing behind.
"""
from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

from harness.common.errors import BadInput

LOCK_NAME = "run.lock"
_NO_FLOCK = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL)  # a file system without flock


def _holder(fd: int) -> int | None:
    """The pid written in an open lock file, or None (empty, or being written)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() and len(text) < 12 else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the open file ``fd`` (a releasing holder removes it)."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except FileNotFoundError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def open_nofollow(path: Path, flags: int) -> int:
    """``os.open(path, flags)`` that refuses a symbolic link at ``path`` (BadInput): a run
    never writes through a link into a file elsewhere."""
    try:
        return os.open(path, flags | getattr(os, "O_NOFOLLOW", 0), 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise BadInput(f"{path} is a symbolic link: a run writes only its own files; remove the link, "
                           "or choose another folder") from None
        raise


def folder_identity(folder: Path) -> tuple[int, int]:
    """(device, inode) of ``folder``: which folder it is, whatever its path names later."""
    st = os.stat(folder)
    return st.st_dev, st.st_ino


def check_folder(folder: Path, identity: tuple[int, int]) -> None:
    """OSError (ESTALE, naming ``folder``) unless ``folder`` is still the folder of
    ``identity``: a run folder removed (and perhaps made again) while a run writes into it
    must not get the rest of that run's files."""
    try:
        same = folder_identity(folder) == tuple(identity)
    except OSError:
        same = False
    if not same:
        raise OSError(errno.ESTALE, "the run folder was removed or replaced while the run ran", str(folder))


class FolderLock:
    """``with FolderLock(folder):`` the folder is this process's until the block ends.

    Raises BadInput if another live process holds it, or if the folder cannot be created
    or written (naming it and the reason)."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None
        self._created: list[Path] = []  # folders made here, outermost first

    def __enter__(self) -> "FolderLock":
        missing = []
        p = self.folder
        while not p.exists() and p != p.parent:
            missing.append(p)
            p = p.parent
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._created = missing[::-1]
            self._fd = self._acquire()
        except OSError as exc:
            self._remove_created()
            raise BadInput(f"{self.folder}: cannot create or write this folder ({exc.strerror or exc}); "
                           "choose another folder, or make it writable") from None
        except BaseException:
            self._remove_created()
            raise
        return self

    def _acquire(self) -> int:
        """The open, locked lock file holding this pid; BadInput if a live process holds it."""
        while True:
            fd = open_nofollow(self.path, os.O_RDWR | os.O_CREAT)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pid = _holder(fd)
                os.close(fd)
                raise self._busy(pid) from None
            except OSError as exc:
                if exc.errno not in _NO_FLOCK:
                    os.close(fd)
                    raise
                pid = _holder(fd)
                if pid is not None and pid != os.getpid() and _alive(pid):
                    os.close(fd)
                    raise self._busy(pid) from None
            if _same_file(fd, self.path):  # else a holder removed it meanwhile: lock the new one
                break
            os.close(fd)
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except BaseException:
            os.close(fd)
            raise
        return fd

    def _busy(self, pid: int | None) -> BadInput:
        who = f"pid {pid}" if pid is not None else "another process"
        return BadInput(f"{self.folder} is in use by another run ({who}, lock {LOCK_NAME}): wait for it to end, "
                        "or choose another folder")

    def _remove_created(self) -> None:
        """Remove the folders made by __enter__ that are still empty, innermost first."""
        for d in reversed(self._created):
            try:
                d.rmdir()
            except OSError:
                break

    def __exit__(self, *exc) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink()  # while still held: a waiting process then locks a new file
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None
        self._remove_created()
