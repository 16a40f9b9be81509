"""The software a run records (harness.provenance): the code digest covers the files that
can change a record and nothing else; library versions are the installed ones."""
from __future__ import annotations

import importlib.metadata
import re

from harness import provenance


def test_the_code_digest_follows_sources_nets_and_checkpoints_only(tmp_path, monkeypatch):
    roots = {name: tmp_path / name for name in provenance.PACKAGES}
    for root in roots.values():
        (root / "sub").mkdir(parents=True)
        (root / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(provenance, "_package_dir", lambda name: roots[name])
    base = provenance.code_digest()
    assert re.fullmatch(r"[0-9a-f]{16}", base)
    # files that cannot change a record: docs, bytecode
    (roots["harness"] / "notes.md").write_text("words")
    (roots["harness"] / "__pycache__").mkdir()
    (roots["harness"] / "__pycache__" / "a.cpython-311.py").write_text("cached")
    assert provenance.code_digest() == base
    # each kind that can, anywhere in a stage's tree, and a file's place as well as its bytes
    for path, text in ((roots["model"] / "sub" / "student.pt", "weights"), (roots["sumo_nets"] / "t.net.xml", "<net/>"),
                       (roots["harness"] / "a.py", "x = 2\n")):
        before = provenance.code_digest()
        path.write_text(text)
        assert provenance.code_digest() != before, path
    before = provenance.code_digest()
    (roots["scimm"] / "a.py").rename(roots["scimm"] / "sub" / "a.py")
    assert provenance.code_digest() != before


def test_software_names_the_installed_libraries_and_this_code():
    sw = provenance.software()
    assert sw["code"] == provenance.code_digest()  # the real stages, found without importing them
    for lib in provenance.LIBRARIES:
        assert sw[lib] == importlib.metadata.version(lib)
    assert sw["libsumo"] == "1.28.0" and sw["onnxruntime"] == "1.32.0"  # the pins of pyproject.toml


def test_a_config_digest_is_of_the_bytes_and_of_a_folders_files(tmp_path):
    f = tmp_path / "student.pt"
    f.write_bytes(b"one")
    one = provenance.config_digest(str(f))
    f.write_bytes(b"two!")  # read again: its size changed (and its time, on most file systems)
    assert provenance.config_digest(str(f)) != one
    folder_digest = provenance.config_digest(str(tmp_path))
    (tmp_path / "manifest.json").write_text("{}")
    assert provenance.config_digest(str(tmp_path)) != folder_digest
    assert provenance.config_digest(str(tmp_path / "missing.pt")) is None
