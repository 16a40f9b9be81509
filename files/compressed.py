"""Text files read the same whether kept plain (``NAME``) or gzip-compressed (``NAME.gz``).

A run folder of ``sumo-scimm eval`` may be archived with its records compressed
(``records.csv.gz``, ``results.json.gz``: a hundred routes' records in about 27 kB instead of
210 kB), as the experiment's committed records are; ``sumo-scimm report`` reads either.
``gzip_copy`` makes such a file: byte-identical for identical input (no time stamp, no
name in the gzip header), so an archive changes only where a record changed.
"""
from __future__ import annotations

import gzip
import zlib
from pathlib import Path

from files.atomic import write_atomic

MAX_TEXT = 512 * 2**20  # [bytes] of decompressed text: a run of 100,000 route runs writes about 180 MB


def stored(path: Path) -> Path | None:
    """``path`` if it is a file, else ``path.gz`` if that is one, else None."""
    path = Path(path)
    if path.is_file():
        return path
    packed = path.with_name(path.name + ".gz")
    return packed if packed.is_file() else None


def read_text(path: Path) -> str:
    """The text of ``path``, or of ``path.gz`` when only that exists (UTF-8); a file whose
    name ends in ``.gz``, given or found, is decompressed. OSError (FileNotFoundError naming
    ``path``) when neither is a file; a damaged or cut-short ``.gz``, or one that would
    decompress to more than MAX_TEXT bytes (a "zip bomb"), raises OSError too
    (gzip.BadGzipFile), having decompressed at most that much."""
    found = stored(path)
    if found is None:
        raise FileNotFoundError(2, "No such file (nor a .gz of it)", str(path))
    if found.name.endswith(".gz"):
        try:
            with gzip.open(found, "rb") as f:
                data = f.read(MAX_TEXT + 1)
        except (EOFError, zlib.error) as exc:  # cut short, or corrupt inside
            raise gzip.BadGzipFile(str(exc)) from None
        if len(data) > MAX_TEXT:
            raise gzip.BadGzipFile(f"it decompresses to more than {MAX_TEXT // 2**20} MB")
        return data.decode()
    return found.read_text()


def gzip_copy(src: Path, dest: Path) -> None:
    """Write ``src`` gzip-compressed to ``dest`` (whole or not at all), reproducibly: the
    same bytes for the same content (mtime 0, no file name in the header, level 9)."""
    write_atomic(dest, gzip.compress(Path(src).read_bytes(), compresslevel=9, mtime=0))
