"""The ``sumo-scimm`` command line: one subcommand per stage of the data flow (docs/design.md §1),
every one registered here.

``main(argv) -> int`` is importable and testable. Results go to stdout; diagnostics (what
a stage wrote where) go through ``logging`` to stderr. Bad input (unknown town or set,
malformed file, bad option, an output path that cannot be created or written) prints one
line ``sumo-scimm: error: ...`` naming the problem and the fix, and returns 2; no
traceback, no partial output. A long number in such a line is cut (a file or an option
may hold one of any length).
"""
from __future__ import annotations

import os

# Before anything imports NumPy: no transparent huge pages for its large arrays (the IMM
# runs faster without them where the kernel's THP mode is "madvise", docs/teacher.md; the
# closed loop and the training do not move). Workers and the bench's IMM process inherit
# it; a value the user set is kept.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

import argparse  # noqa: E402
import errno  # noqa: E402
import logging  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402

from harness.common.errors import BadInput  # noqa: E402
from sumo_scimm import model_commands, run_commands, teacher_commands, world_commands  # noqa: E402
from sumo_scimm.bench import command as bench_command  # noqa: E402
from sumo_scimm import replay_commands  # noqa: E402
from sumo_scimm.options import EXIT_BAD_INPUT, Parser  # noqa: E402

# in the order of the data flow: nets, routes | eval, render, score, report, collect, data |
# replay | teacher | train, reproduce | bench
COMMANDS = (world_commands, run_commands, replay_commands, teacher_commands, model_commands, bench_command)


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's or ``kill``'s stop), raised in the main thread so a run ends as
    after a Ctrl-C: workers stopped, the records written so far complete, resumable."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand."""
    p = Parser(prog="sumo-scimm", description="Closed-loop driving benchmark on SUMO with "
               "Leaderboard 2.0 scoring and SC-IMM teacher signals.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    for module in COMMANDS:
        module.register(sub)
    return p


class _Stderr(logging.Handler):
    """Log records as plain lines on whatever ``sys.stderr`` is when they are emitted."""

    def emit(self, record: logging.LogRecord) -> None:
        sys.stderr.write(self.format(record) + "\n")


def _log_to_stderr() -> None:
    """Diagnostics of the stages (``logging``, INFO and up) as plain lines on stderr, once
    per process however often ``main`` runs."""
    root = logging.getLogger()
    if not any(isinstance(h, _Stderr) for h in root.handlers):
        root.addHandler(_Stderr())
        root.setLevel(logging.INFO)


def _os_error(exc: OSError) -> str:
    """One line for an OSError: what failed, on which path, and the fix."""
    where = f": {exc.filename}" if exc.filename else ""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        fix = "free some space, then run the command again"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        fix = "make the path writable, or choose another one"
    elif exc.errno == errno.EPIPE:
        fix = "the program reading the output closed it first"
    else:
        fix = "check the path: its folder must exist or be creatable, and be writable"
    return f"{exc.strerror or exc}{where} ({fix})"


MESSAGE_MAX = 600  # [characters] of an error line; a longer one keeps its start and its end (the fix)


def one_line(text: str) -> str:
    """An error message as one line: its line breaks become ' | ' (an agent's or a library's
    exception text may hold several lines), and one longer than MESSAGE_MAX characters
    keeps its first 300 and last 250 (where the fix is), the cut said."""
    text = re.sub(r"\s*[\r\n]+\s*", " | ", text.strip())
    if len(text) <= MESSAGE_MAX:
        return text
    return f"{text[:300]} ... ({len(text) - 550} characters left out) ... {text[-250:]}"


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code. A Ctrl-C or SIGTERM ends the run with
    130 or 143, the records written so far complete and resumable."""
    from scenarios import UnknownSet
    from scenarios.routefile import RouteFileError, clip_numbers
    from sumo_nets import UnknownTown
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main else None
    _log_to_stderr()
    args = None
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except (BadInput, UnknownTown, UnknownSet, RouteFileError) as exc:
        print(f"sumo-scimm: error: {one_line(clip_numbers(str(exc)))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # a path the command cannot create, read or write (a route's own failures are records)
        print(f"sumo-scimm: error: {one_line(_os_error(exc))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        # eval and collect keep what they wrote
        hint = "; the same command with --resume goes on from here" if getattr(args, "resume", None) is not None else ""
        if isinstance(exc, Terminated):
            print(f"sumo-scimm: terminated (SIGTERM){hint}", file=sys.stderr)
            return 128 + signal.SIGTERM
        print(f"sumo-scimm: interrupted{hint}", file=sys.stderr)
        return 130
    finally:
        if in_main and previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
