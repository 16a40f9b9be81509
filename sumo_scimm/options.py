"""Options and conventions shared by every subcommand: the one-line usage error, seeds, the
agent and the backend options."""
from __future__ import annotations

import argparse

from harness.common.errors import BadInput
from harness.loop.agent import DEFAULT_AGENT
from harness.runs.evaluate import Backend

EXIT_BAD_INPUT = 2


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (and exit code 2)."""

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        raise BadInput(f"{message} (see '{self.prog} --help')")


def seed_arg(text: str) -> int:
    """argparse type of every --seed: an integer >= 0 (numpy's SeedSequence takes no negative)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"invalid seed {value}: must be >= 0")
    return value


def out_arg(text: str) -> str:
    """argparse type of a command's output folder or file: not empty (an empty --out would
    name the current folder, or fall back to a default one, such as a shipped file)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is empty: give a path")
    return text


def add_agent_options(p: argparse.ArgumentParser) -> None:
    """--agent and --agent-config."""
    p.add_argument("--agent", default=DEFAULT_AGENT,
                   help=f"agent name, module:Class, or a student checkpoint (.pt) (default {DEFAULT_AGENT})")
    p.add_argument("--agent-config", help="file passed to the agent's setup()")


def add_vehicle_option(p: argparse.ArgumentParser) -> None:
    """--vehicle: the ego model (controller.ego)."""
    from controller.ego import DEFAULT_VEHICLE, VEHICLES
    p.add_argument("--vehicle", default=DEFAULT_VEHICLE, choices=tuple(VEHICLES),
                   help=f"ego model: carla (CARLA's Lincoln MKZ: engine, gearbox, brakes, tyres) or kinematic "
                        f"(PDM-Lite's kinematic bicycle) (default {DEFAULT_VEHICLE}; docs/vehicle.md)")


def add_backend_options(p: argparse.ArgumentParser) -> None:
    """--backend and --address (the --workers option is each command's own)."""
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="local worker processes, or Ray tasks (needs the 'ray' extra; see docs/cluster.md)")
    p.add_argument("--address", help="Ray cluster to join (host:port of its head, ray://host:port, or auto); "
                   "default: a local Ray on --workers CPUs")


def backend_of(args: argparse.Namespace) -> Backend:
    """The Backend the parsed options name."""
    return Backend(getattr(args, "workers", None), args.backend, args.address)
