"""A real `eval --rules b2d` run (libsumo): its folder is what Bench2Drive's tools read.
results.json is the only *.json at the top (merge_route_json.py reads every one), each
record names the folder of its route's metric_info.json, which holds one entry per tick of
the route's log, and the smoothness in the record is the one its file gives."""
from __future__ import annotations

import json

import numpy as np

from harness.scoring.bench2drive import route_smoothness
from sumo_scimm.cli import main

ARGV = ["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "route_follower", "--workers", "1",
        "--rules", "b2d"]


def test_a_b2d_run_folder_is_what_bench2drives_tools_read(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*ARGV, "--out", str(out)]) == 0
    assert ", SR " in capsys.readouterr().out
    assert sorted(p.name for p in out.glob("*.json")) == ["results.json"]
    results = json.loads((out / "results.json").read_text())
    assert results["entry_status"] == "Finished" and results["eligible"] is True
    (lb,) = results["_checkpoint"]["records"]
    # route 0's first scenario is SignalizedJunction_1 (scenarios/town12_smoke.xml)
    assert lb["scenario_name"] == "SignalizedJunction_1" and lb["town_name"] == "town12" and lb["weather_id"] is None
    info = json.loads((out / "b2d" / lb["save_name"] / "metric_info.json").read_text())
    with np.load(out / "logs" / "0_rep0.npz") as log:
        assert list(info) == [str(k) for k in range(len(log["t"]))]
    arrays = {f: np.array([v[f] for v in info.values()]) for f in info["0"]}
    (rec,) = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert rec["smoothness"] == route_smoothness(arrays)
    assert rec["efficiency"] is not None and rec["hazard"] == "SignalizedJunction"


def test_resume_renames_the_run_json_of_an_older_folder(tmp_path):
    out = tmp_path / "run"
    assert main([*ARGV, "--out", str(out)]) == 0
    identity = (out / "run.jsonc").read_text()
    (out / "run.jsonc").rename(out / "run.json")
    assert main([*ARGV, "--out", str(out), "--resume"]) == 0
    assert not (out / "run.json").exists()
    assert (out / "run.jsonc").read_text() == identity
