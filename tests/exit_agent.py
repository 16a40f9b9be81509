"""A user's agent that writes a line from an ``atexit`` function, as agents that flush a log
when their process ends do: the route follower, plus the line "<pid> drove <ticks> ticks"
appended to the file named by AGENT_EXIT_FILE when its process exits."""
import atexit
import os

from harness.loop.route_follower import RouteFollower


class WritesAtExit(RouteFollower):
    ticks = 0  # ticks driven by this process's instances

    def run_step(self, input_data, timestamp):
        if WritesAtExit.ticks == 0:  # run_step runs in the worker only (not in the agent's checks)
            atexit.register(_write, os.environ["AGENT_EXIT_FILE"])
        WritesAtExit.ticks += 1
        return super().run_step(input_data, timestamp)


def _write(path: str) -> None:
    with open(path, "a") as f:
        f.write(f"{os.getpid()} drove {WritesAtExit.ticks} ticks\n")
