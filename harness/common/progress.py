"""Progress of a long command: a tqdm bar on a terminal; in a log (a pipe, a file, a batch
job's output) a plain line at most every LOG_EVERY seconds, the first after LOG_EVERY
seconds and the last when the work ends, so a short command prints none.

tqdm draws its bar by rewriting one line with carriage returns, which a log keeps as one
ever-growing line; outside a terminal ``progress`` gives tqdm a stream that turns each
redraw into a line of its own.
"""
from __future__ import annotations

import sys
from typing import Iterable, TextIO

from tqdm import tqdm

LOG_EVERY = 30.0  # seconds between two progress lines in a log, and before the first one


class _Lines:
    """A text stream for tqdm outside a terminal: each redraw becomes one line."""

    def __init__(self, stream: TextIO):
        self.stream = stream

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip("\n")
        if line.strip():
            self.stream.write(line + "\n")

    def flush(self) -> None:
        self.stream.flush()


def progress(iterable: Iterable | None = None, *, total: float | None = None, desc: str = "", unit: str = "it",
             initial: float = 0, show: bool = True) -> tqdm:
    """A tqdm progress bar over ``iterable`` or of ``total`` units, on stderr: drawn in
    place on a terminal, as lines at most every LOG_EVERY s elsewhere; nothing with
    ``show`` False."""
    if not show:
        return tqdm(iterable, total=total, disable=True)
    if sys.stderr.isatty():
        return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial)
    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, file=_Lines(sys.stderr),
                mininterval=LOG_EVERY, maxinterval=LOG_EVERY, delay=LOG_EVERY, ascii=True, ncols=100)
