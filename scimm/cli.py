"""``sumo-scimm teacher ...`` subcommands (registered by ``harness.cli``)."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add this stage's subcommands to the ``sumo-scimm`` parser."""
