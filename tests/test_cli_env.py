"""The CLI turns NumPy's transparent huge pages off before NumPy loads (docs/teacher.md: with
THP on madvise, they made the IMM slower and its timing erratic), and keeps a value the user
set."""
from __future__ import annotations

import os
import subprocess
import sys

CODE = ("from sumo_scimm.cli import main; import os, numpy as np; "
        "print(os.environ['NUMPY_MADVISE_HUGEPAGE'], np._core.multiarray._get_madvise_hugepage())")


def _run(env_value: str | None) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if env_value is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = env_value
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_the_cli_loads_numpy_without_huge_pages_unless_the_user_asks():
    assert _run(None) == ["0", "False"]  # set before NumPy was imported, so NumPy follows it
    assert _run("1") == ["1", "True"]
