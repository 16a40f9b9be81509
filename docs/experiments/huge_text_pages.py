"""Does code on 2 MB pages make a closed-loop tick cheaper? (docs/scale.md, session 12)

Copies the executable text of the loaded libraries (torch, libsumo, OpenCV, numpy, ...)
onto anonymous 2 MB pages and remaps it in place, as Intel's iodlr does, then drives
routes of ``town12_short`` with the shipped SC-IMM student in this process and prints the
loop's ms per tick. Run it with and without ``--huge``, in alternation; Linux only, THP in
``madvise`` or ``always`` mode. Measured on the AMD EPYC VM: no gain beyond the noise,
about 580 MB more resident memory.

    python docs/experiments/huge_text_pages.py [--huge] [ROUTE_INDICES]   (default 1,3,4)
"""
import ctypes
import sys

from harness.loop.episode import run_episode
from harness.runs.runner import route_seed
from scenarios import resolve_set
from scenarios.routefile import read_routes

H = 2 << 20  # 2 MB
PROT_RW, PROT_RX, MAP_PRIVATE_ANON, MREMAP_MAYMOVE_FIXED, MADV_HUGEPAGE = 3, 5, 0x22, 3, 14


def remap_text_to_huge_pages(patterns=("site-packages",)) -> int:
    """Remap the 2 MB-aligned part of every executable mapping whose path contains one of
    ``patterns`` onto anonymous huge pages; returns the MB remapped."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mmap.restype = libc.mremap.restype = ctypes.c_void_p
    libc.mmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long]
    libc.mremap.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t, ctypes.c_int, ctypes.c_void_p]
    for f in (libc.madvise, libc.mprotect):
        f.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    libc.memcpy.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t]
    total = 0
    for parts in [line.split() for line in open("/proc/self/maps")]:
        if len(parts) < 6 or "x" not in parts[1] or not any(p in parts[5] for p in patterns):
            continue
        a, b = (int(v, 16) for v in parts[0].split("-"))
        a, b = (a + H - 1) // H * H, b // H * H
        if b <= a:
            continue
        raw = libc.mmap(None, b - a + H, PROT_RW, MAP_PRIVATE_ANON, -1, 0)
        tmp = (raw + H - 1) // H * H
        libc.madvise(tmp, b - a, MADV_HUGEPAGE)
        libc.memcpy(tmp, a, b - a)
        libc.mprotect(tmp, b - a, PROT_RX)
        if libc.mremap(tmp, b - a, b - a, MREMAP_MAYMOVE_FIXED, a) == a:
            total += (b - a) >> 20
    return total


if __name__ == "__main__":
    import cv2  # noqa: F401 - load every library before remapping
    import libsumo  # noqa: F401
    import torch  # noqa: F401
    args = [a for a in sys.argv[1:] if a != "--huge"]
    if "--huge" in sys.argv:
        print(f"remapped {remap_text_to_huge_pages()} MB of code onto 2 MB pages")
    _, routes = read_routes(resolve_set("town12_short"))
    ticks = loop = 0.0
    for i in [int(a) for a in (args[0] if args else "1,3,4").split(",")]:
        r = run_episode(routes[i], "scimm", None, route_seed(0, i))
        ticks, loop = ticks + r.steps, loop + r.loop_time
    print(f"{1000 * loop / ticks:.3f} ms a tick over {int(ticks)} ticks")
