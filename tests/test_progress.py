"""Progress outside a terminal (harness.common.progress): lines in a log, none for short work."""
from __future__ import annotations

import io

from harness.common import progress as P


def test_a_log_gets_whole_lines_and_short_work_none(monkeypatch):
    log = io.StringIO()  # not a terminal, as a pipe, a file or a batch job's output
    monkeypatch.setattr(P.sys, "stderr", log)
    for _ in P.progress(range(3), desc="quick", unit="route"):
        pass
    assert log.getvalue() == ""  # done before LOG_EVERY: nothing to read in the log
    monkeypatch.setattr(P, "LOG_EVERY", 0.0)
    bar = P.progress(total=2, desc="eval", unit="route")
    bar.update(1)
    bar.update(1)
    bar.close()
    lines = log.getvalue().split("\n")
    assert lines[-1] == "" and "\r" not in log.getvalue()  # every redraw a line of its own
    assert lines[-2].startswith("eval: 100%") and "2/2" in lines[-2]
    assert all(line.startswith("eval: ") for line in lines[:-1])


def test_show_false_prints_nothing(monkeypatch):
    log = io.StringIO()
    monkeypatch.setattr(P.sys, "stderr", log)
    bar = P.progress(total=5, desc="eval", unit="route", show=False)
    bar.update(5)
    bar.close()
    assert log.getvalue() == ""
