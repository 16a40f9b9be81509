"""Does a core's cache cool with the time spent elsewhere? Two measurements (session 11).

    python docs/experiments/cache_cooling.py [ROUTE_INDICES]

1. The same 1 MB array (it fits the 2 MB L2 per core of the Intel Xeon VM of session 11;
   the AMD EPYC VM of session 12 has 1 MB per core) is summed right
   after a busy spin of 0 to 10 ms that touches almost no memory. On a machine whose
   caches belong to this process alone the time does not depend on the spin.
2. SUMO's step (``Scene.advance``, the ``bare libsumo`` figure of ``sumo-scimm bench``)
   replays the logged ego of one episode of the shipped SC-IMM student, with nothing,
   a 1 ms busy spin, a 1 ms sleep or the student's network run (untimed) before every
   step. ROUTE_INDICES: town12_smoke route indices, comma-separated (default 1).

Each variant runs ``REPEATS`` times in turn; the figures are the medians (1) and the
means per tick (2) of each run. Analysis only: it changes no record.
"""
from __future__ import annotations

import sys
import time

import numpy as np

REPEATS = 3
SPINS_MS = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0)


def spin(seconds: float) -> None:
    """Busy-wait: the core stays with this process, touching almost no memory."""
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        pass


def reread_us(spin_s: float, a: np.ndarray, n: int = 300) -> float:
    """Median time [us] of ``a.sum()`` right after a spin of spin_s seconds."""
    times = []
    for _ in range(n):
        spin(spin_s)
        t = time.perf_counter()
        a.sum()
        times.append(time.perf_counter() - t)
    return float(np.median(times)) * 1e6


def main(route_indices: list[int]) -> None:
    a = np.ones(2**20 // 8)  # 1 MB
    runs: dict[float, list[float]] = {ms: [] for ms in SPINS_MS}
    for _ in range(REPEATS):
        for ms in SPINS_MS:
            runs[ms].append(reread_us(ms * 1e-3, a))
    print("1 MB re-read after a busy spin (median us, one value per run):")
    for ms, v in runs.items():
        print(f"  spin {ms:5.1f} ms: {', '.join(f'{x:.1f}' for x in v)}")

    from harness.runs.bench import _bare_step_ms
    from harness.loop.episode import run_episode
    from harness.runs.runner import route_seed
    from model.agent import ScimmStudent
    from model.cache import binarize
    from scenarios import resolve_set
    from scenarios.routefile import read_routes
    _, routes = read_routes(resolve_set("town12_smoke"))
    agent = ScimmStudent()
    agent.setup(None)
    x = binarize(np.zeros((9, 64, 64), dtype=np.uint8))
    variants = {"nothing": None, "1 ms spin": lambda: spin(1e-3), "1 ms sleep": lambda: time.sleep(1e-3),
                "the network": lambda: agent.infer(x, np.array([18.0, 0.0]), 5.0)}
    for k in route_indices:
        res = run_episode(routes[k], "scimm", None, route_seed(0, k))
        step: dict[str, list[float]] = {name: [] for name in variants}
        for _ in range(REPEATS):
            for name, between in variants.items():
                ms, same = _bare_step_ms(routes[k], route_seed(0, k), res.log, between=between)
                assert same, "the replay did not reproduce the episode's traffic"
                step[name].append(ms)
        print(f"SUMO step, town12_smoke route {k} ({res.steps} ticks), ms per tick, with before every step:")
        for name, v in step.items():
            print(f"  {name:12s} {', '.join(f'{x:.3f}' for x in v)}")


if __name__ == "__main__":
    main([int(i) for i in sys.argv[1].split(",")] if len(sys.argv) > 1 else [1])
