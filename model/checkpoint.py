"""Student model checkpoints: weights + architecture config + manifest, one small file.

File layout (``torch.save`` of plain containers only, so it loads with
``torch.load(weights_only=True)``, which refuses any pickle that would run code)::

    {"format": FORMAT, "state_dict": {name: tensor}, "config": NetConfig as dict,
     "manifest": {data hash, teacher, seed, git commit, epochs, final losses, ...}}

The manifest is also written beside it as ``manifest.json`` for people. Files are written
to a temporary name, then renamed, so a killed save never leaves a half-written file.

A damaged file is refused when loaded: every member's CRC in the zip archive is checked,
and the weights' content hash (``weights_sha256``: sha256 over the tensors' names, dtypes,
shapes and bytes, ``weights_digest``) must equal the one in the manifest (the file's own,
or, for a file saved before the hash was kept, the ``manifest.json`` beside it).
"""
from __future__ import annotations

import hashlib
import json
import pickle
import subprocess
import zipfile
from pathlib import Path

import torch

from files.atomic import write_atomic
from harness.common.errors import BadInput
from model.network import NetConfig, Student

FORMAT = "sumo-scimm-student/1"
ZIP_MAGIC, PICKLE_PROTO = b"PK\x03\x04", b"\x80"  # how torch files start: zip (torch.save), legacy pickle
WEIGHTS_NAME = "student.pt"  # file name inside a training's --out folder
HISTORY_NAME = "history.json"  # beside it: per-epoch losses, the chosen epoch (model.train, model.curves)


def git_commit() -> str:
    """The project's git commit (with '-dirty' for uncommitted changes), or 'unknown'."""
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("-dirty" if dirty else "")


def weights_digest(state_dict: dict) -> str:
    """sha256 (hex) over the tensors of ``state_dict``, by name: name, dtype, shape, bytes."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def save_checkpoint(path: Path, model: Student, manifest: dict) -> Path:
    """Write model weights, config and manifest (with the weights' ``weights_sha256``) to
    ``path`` and manifest.json beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    manifest = {**manifest, "weights_sha256": weights_digest(state)}
    blob = {"format": FORMAT, "state_dict": state, "config": model.cfg.to_dict(), "manifest": manifest}
    write_atomic(path, lambda tmp: torch.save(blob, tmp))
    write_atomic(path.with_name("manifest.json"), json.dumps(manifest, indent=2, sort_keys=True))
    return path


def resolve(path: str | Path) -> Path:
    """A model checkpoint file, or a training --out folder holding student.pt."""
    p = Path(path)
    return p / WEIGHTS_NAME if p.is_dir() else p


def load_checkpoint(path: str | Path) -> tuple[Student, dict]:
    """(model in eval mode, manifest); BadInput (one line) for a missing, corrupt or unsafe file."""
    p = resolve(path)
    if not p.is_file():
        raise BadInput(f"model checkpoint {p} not found (train one with 'sumo-scimm train --data DIR --out DIR')")
    try:
        with open(p, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise BadInput(f"model checkpoint {p} cannot be read ({exc.strerror or exc})") from None
    if head != ZIP_MAGIC and head[:1] != PICKLE_PROTO:
        raise BadInput(f"model checkpoint {p} is not a torch file (it starts with {head!r}); use a file written "
                       "by 'sumo-scimm train'")
    if head == ZIP_MAGIC:
        _check_crcs(p)
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BadInput(f"model checkpoint {p} refused: it holds Python objects that weights_only loading does "
                       f"not allow and could run code ({first[:120]}); use a file written by 'sumo-scimm train'") from None
    except (RuntimeError, EOFError, OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise BadInput(f"model checkpoint {p} is corrupt or not a torch file ({type(exc).__name__}); "
                       f"retrain with 'sumo-scimm train'") from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise BadInput(f"model checkpoint {p} is not a {FORMAT} file; use a file written by 'sumo-scimm train'")
    try:
        model = Student(NetConfig(**{"speed_input": True, **blob["config"]}))
        model.load_state_dict(blob["state_dict"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise BadInput(f"model checkpoint {p} does not match the student network ({type(exc).__name__}: "
                       f"{str(exc).splitlines()[0][:120]}); retrain with 'sumo-scimm train'") from None
    manifest = _check_digest(p, blob["state_dict"], dict(blob.get("manifest", {})))
    model.eval()
    return model, manifest


def _check_crcs(p: Path) -> None:
    """BadInput unless every member of the zip archive ``p`` reads back with its CRC."""
    try:
        with zipfile.ZipFile(p) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, OSError, RuntimeError, ValueError, EOFError) as exc:
        raise BadInput(f"model checkpoint {p} is corrupt ({type(exc).__name__}); retrain with 'sumo-scimm train', "
                       "or copy it again") from None
    if bad is not None:
        raise BadInput(f"model checkpoint {p} is damaged: {bad} fails its CRC check; copy the file again, or "
                       "retrain with 'sumo-scimm train'")


def _check_digest(p: Path, state_dict: dict, manifest: dict) -> dict:
    """The manifest, with the weights' hash it was checked against; BadInput unless the
    weights' hash is the manifest's (or, without one there, the ``manifest.json`` beside
    ``p``'s); a checkpoint with neither is not checked."""
    expected = manifest.get("weights_sha256")
    beside = p.with_name("manifest.json")
    if expected is None and beside.is_file():
        try:
            expected = json.loads(beside.read_text()).get("weights_sha256")
        except (OSError, ValueError, AttributeError):
            expected = None
    if expected is not None and weights_digest(state_dict) != expected:
        raise BadInput(f"model checkpoint {p}: its weights do not match the weights_sha256 of its manifest (the "
                       "file was changed); copy it again, or retrain with 'sumo-scimm train'")
    return manifest if expected is None else {**manifest, "weights_sha256": expected}
