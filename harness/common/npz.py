"""Reading .npz files (episodes, logs, teacher files) that may be damaged: every way one can
be (empty, cut short, not an .npz file, an array missing, an array of Python objects,
which are never unpickled, an array of another shape or number of rows) becomes one
BadInput line naming the file, the problem and the fix."""
from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from harness.common.errors import BadInput

def _npz_error(path: Path, what: str, fix: str, exc: BaseException, name: str = "") -> BadInput:
    """The one line for ``exc`` raised opening ``path`` (or reading its array ``name``)."""
    detail = f"{type(exc).__name__}: {exc}"
    if isinstance(exc, FileNotFoundError):
        return BadInput(f"{what} {path} does not exist: {fix}")
    if isinstance(exc, KeyError):
        problem = f"it has no '{name}' array"
    elif isinstance(exc, EOFError) and not name:
        problem = "it is empty" if path.stat().st_size == 0 else "it is cut short"
    elif isinstance(exc, ValueError) and "allow_pickle" in str(exc) and name:
        problem = f"array '{name}' holds Python objects, which are never unpickled"
    elif name:
        problem = f"array '{name}' is cut short or damaged: {detail}"
    else:
        problem = f"it is not an .npz file: {detail}"
    return BadInput(f"{what} {path} is damaged ({problem}): {fix}")


NPZ_ERRORS = (EOFError, OSError, ValueError, KeyError, zipfile.BadZipFile, zlib.error)


def _open_npz(path: Path, what: str, fix: str) -> np.lib.npyio.NpzFile:
    try:
        z = np.load(path, allow_pickle=False)
    except NPZ_ERRORS as exc:
        raise _npz_error(path, what, fix, exc) from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise BadInput(f"{what} {path} is a single .npy array, not an .npz file: {fix}")
    return z


def read_npz(path: Path, what: str, fix: str, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The arrays ``keys`` (default all) of the .npz file ``path``. Every way the file can be
    damaged (empty, cut short, not an .npz file, an array of Python objects, which are never
    unpickled, a missing array) is BadInput naming ``what`` (e.g. "episode file") and the
    file, the problem and ``fix``."""
    path = Path(path)
    name = ""
    with _open_npz(path, what, fix) as z:
        try:
            out = {}
            for name in (z.files if keys is None else keys):
                out[name] = z[name]
            return out
        except NPZ_ERRORS as exc:
            raise _npz_error(path, what, fix, exc, name) from None


def npz_headers(path: Path, what: str, fix: str) -> dict[str, np.ndarray]:
    """{array name: a stand-in of the array} of the .npz file ``path``: the shape and dtype
    from the array's header, no data read (every element reads as the first of a zero
    array; for check_rows). BadInput as read_npz."""
    path = Path(path)
    name = ""
    with _open_npz(path, what, fix) as z:
        try:
            out = {}
            for name in z.files:
                with z.zip.open(f"{name}.npy") as f:
                    version = np.lib.format.read_magic(f)
                    if version not in ((1, 0), (2, 0)):
                        out[name] = z[name]
                        continue
                    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                        np.lib.format.read_array_header_2_0
                    shape, _, dtype = read(f)
                out[name] = np.lib.stride_tricks.as_strided(np.zeros(1, dtype), shape, (0,) * len(shape))
            return out
        except NPZ_ERRORS as exc:
            raise _npz_error(path, what, fix, exc, name) from None


def check_rows(arrays: dict[str, np.ndarray], rows: dict[str, tuple], path: Path, what: str, fix: str,
               n: int | None = None) -> int:
    """The number of rows the arrays ``rows`` ({name: shape of one row, None = any size})
    share (``n`` if given); BadInput naming the file if one is missing, is not numbers, or
    has another shape or row count."""
    first = None
    for name, shape in rows.items():
        if name not in arrays:
            raise BadInput(f"{what} {path} has no '{name}' array: {fix}")
        a = arrays[name]
        want = ("N", *("*" if s is None else s for s in shape))
        if a.dtype.kind not in "biuf":
            raise BadInput(f"{what} {path}: array '{name}' holds {a.dtype} values, not numbers: {fix}")
        if a.ndim != len(want) or any(s is not None and s != d for s, d in zip(shape, a.shape[1:])):
            raise BadInput(f"{what} {path}: array '{name}' has shape {a.shape}, expected "
                           f"({', '.join(map(str, want))}): {fix}")
        if n is None:
            n, first = len(a), name
        elif len(a) != n:
            raise BadInput(f"{what} {path}: array '{name}' has {len(a)} rows, "
                           f"{f'{first!r} has' if first else 'expected'} {n}: {fix}")
    return n or 0


def check_offsets(arrays: dict[str, np.ndarray], offset: str, rows: dict[str, tuple], n: int, path: Path,
                  what: str, fix: str) -> None:
    """BadInput unless ``arrays[offset]`` (n + 1,) counts up from 0 to the row count of the
    ragged arrays ``rows`` (the actors of frame k: rows offset[k]:offset[k + 1])."""
    total = check_rows(arrays, rows, path, what, fix)
    off = arrays.get(offset)
    if off is None or off.dtype.kind not in "iu" or off.shape != (n + 1,) or off[0] != 0 or off[-1] != total \
            or (np.diff(off) < 0).any():
        shape = None if off is None else off.shape
        raise BadInput(f"{what} {path}: array '{offset}' (shape {shape}) does not count the {total} rows of "
                       f"'{next(iter(rows))}' up over {n} frames: {fix}")
