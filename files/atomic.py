"""Files that are written whole or not at all, even when the run is stopped.

A run is stopped by Ctrl-C (SIGINT) or SIGTERM: the parent ends its workers with SIGTERM.
Every file goes to ``NAME.tmp...`` and is renamed over NAME; ``signals_held`` holds a
SIGINT or SIGTERM that arrives meanwhile and delivers it just after, so a stop never leaves
a half-written temporary file, nor (in the parent) a record in records.jsonl that
records.csv and results.json lack.

A write that fails (a full disk, a read-only or forbidden folder) removes its temporary
file and raises OSError naming the file meant (``path``), not the temporary one.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading
from pathlib import Path
from typing import Callable

import numpy as np


@contextlib.contextmanager
def signals_held():
    """Run the block with SIGINT and SIGTERM held; a held one is delivered again just after
    (the previous handler acts then: a worker's default SIGTERM ends it, a parent's raises).
    Python handles signals in the main thread only; elsewhere the block runs as is, and so
    does a signal whose handler was not set from Python."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    kinds = [k for k in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(k) is not None]
    previous = {k: signal.signal(k, lambda signum, frame: held.append(signum)) for k in kinds}
    try:
        yield
    finally:
        for k, handler in previous.items():
            signal.signal(k, handler)
        for k in dict.fromkeys(held):
            os.kill(os.getpid(), k)  # as if it arrived now


def savez_atomic(path: Path, /, **arrays) -> None:
    """``np.savez_compressed`` to ``path`` via ``path.tmp.npz``, with stops held (``path``
    is positional-only: an array may be called "path")."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    with _replacing(path, tmp):
        np.savez_compressed(tmp, **arrays)


def write_atomic(path: Path, content: str | bytes | Callable[[Path], None], shared: bool = False) -> None:
    """Write ``path`` whole or not at all: ``content`` (text, bytes, or a function that
    writes the file it is given) goes to ``path.tmp``, which is renamed over ``path`` with
    stops held. ``shared``: several processes may write ``path`` at once (the same
    content), each through its own ``path.tmp<pid>``. A write that fails (a full disk, a
    folder in the way) removes the temporary file and raises (an OSError naming ``path``)."""
    path = Path(path)
    tmp = path.with_name(path.name + (f".tmp{os.getpid()}" if shared else ".tmp"))
    with _replacing(path, tmp):
        if isinstance(content, str):
            tmp.write_text(content, encoding="utf-8", errors="backslashreplace")
        elif isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            content(tmp)


@contextlib.contextmanager
def _replacing(path: Path, tmp: Path):
    """Stops held while the body writes ``tmp``, which then replaces ``path``; on any failure
    ``tmp`` is removed, and an OSError is raised again naming ``path``."""
    with signals_held():
        try:
            yield
            os.replace(tmp, path)
        except OSError as exc:
            _remove(tmp)
            raise _naming(exc, path) from exc
        except BaseException:
            _remove(tmp)
            raise


def _remove(tmp: Path) -> None:
    """Remove a temporary file (or whatever link stands at its name); a folder in the way stays."""
    try:
        os.unlink(tmp)
    except OSError:
        pass


def _naming(exc: OSError, path: Path) -> OSError:
    """``exc`` as an OSError of the same kind naming ``path`` (the file meant)."""
    if exc.errno is None:
        return OSError(f"{exc}: {path}")
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))
