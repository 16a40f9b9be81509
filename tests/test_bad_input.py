"""Bad input the option fuzz of test_bad_input_fuzz.py does not reach: a resumed folder that
holds another run, output paths that cannot be written, an agent that cannot be built, a
results file with more records than planned routes, damaged run and dataset folders. Each
gives one line, exit code 2, no traceback, and leaves what was there as it was."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from harness.common.errors import BadInput
from tests.run_folder_helpers import _cli, _one_line_exit_2

SMOKE_ROUTE = ["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "route_follower",
               "--workers", "1"]
SMOKE_TWO = [*SMOKE_ROUTE[:4], "0-1", *SMOKE_ROUTE[5:]]  # the same with routes 0 and 1


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def one_route_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "run"
    code, printed = _cli([*SMOKE_ROUTE, "--out", str(out)])
    assert code == 0, printed
    return out


@pytest.mark.parametrize("change, words", [
    (["--agent", "expert"], ["agent 'expert'", "'route_follower'"]),
    (["--seed", "3"], ["seed", "another --seed than the run's"]),
    (["--routes-subset", "1"], ["route runs differ"]),
    (["--rules", "b2d"], ["rules 'b2d'"]),
])
def test_resume_refuses_a_folder_that_holds_another_run(one_route_run, tmp_path, change, words):
    """Before, the records of both runs were mixed: DS 558 on a 100-route folder resumed
    with 10 routes of another agent."""
    out = tmp_path / "run"
    shutil.copytree(one_route_run, out)
    before = _tree(out)
    argv = list(SMOKE_ROUTE)
    for opt, value in zip(change[::2], change[1::2]):
        if opt in argv:
            argv[argv.index(opt) + 1] = value
        else:
            argv += [opt, value]
    code, printed = _cli([*argv, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, *words, "resume with the options the run was started with")
    assert _tree(out) == before


def test_resume_of_a_folder_without_run_json_checks_its_records(one_route_run, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(one_route_run, out)
    (out / "run.jsonc").unlink()
    code, printed = _cli([*SMOKE_ROUTE, "--seed", "3", "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, "record 0_rep0 has seed")
    # the same options: nothing left to run, the scores are printed again; no run.json is
    # written, as it would name software that made none of the records
    code, printed = _cli([*SMOKE_ROUTE, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert "1 routes ->" in printed, printed
    assert not (out / "run.jsonc").exists()
    # with a route left to run: refused, the records' software is unknown
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, "did not record its software", "start the run afresh")


@pytest.fixture(scope="module")
def half_run(tmp_path_factory) -> Path:
    """A run of two routes stopped after the first: one record, one route left."""
    out = tmp_path_factory.mktemp("half") / "run"
    code, printed = _cli([*SMOKE_TWO, "--out", str(out)])
    assert code == 0, printed
    rec = out / "records.jsonl"
    rec.write_text(rec.read_text().splitlines(keepends=True)[0])
    return out


def _with_software(src: Path, dst: Path, entry: str, value: str) -> dict:
    """A copy of run folder src whose run.json names another ``entry`` of the software."""
    shutil.copytree(src, dst)
    identity = json.loads((dst / "run.jsonc").read_text())
    assert identity["software"][entry] not in (None, value)  # recorded when the run started
    identity["software"][entry] = value
    (dst / "run.jsonc").write_text(json.dumps(identity))
    return identity


@pytest.mark.parametrize("entry, value, words", [
    ("onnxruntime", "1.0.0", ["onnxruntime 1.32.0, the run has 1.0.0"]),
    ("libsumo", "1.20.0", ["libsumo 1.28.0, the run has 1.20.0"]),
    ("code", "0123456789abcdef", ["code ", "the run has 0123456789abcdef"]),
])
def test_resume_refuses_a_folder_started_with_other_software(half_run, tmp_path, entry, value, words):
    """Another commit or library gives other trajectories (docs/reliability.md): a run
    resumed with it would mix two versions of the experiment in one score."""
    out = tmp_path / "run"
    _with_software(half_run, out, entry, value)
    before = _tree(out)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, "was started with other software", *words, "another --out")
    assert _tree(out) == before


def test_resume_refuses_another_ego_model(half_run, tmp_path):
    """A run driven with CARLA's car (the default) resumed with the kinematic one would mix
    two ego models in one score: one line naming the model to resume with, nothing written."""
    out = tmp_path / "run"
    shutil.copytree(half_run, out)
    before = _tree(out)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume", "--vehicle", "kinematic"])
    _one_line_exit_2(code, printed, "was driven with --vehicle carla, not kinematic", "resume with --vehicle carla",
                     "another --out")
    assert _tree(out) == before
    assert all(r["vehicle"] == "carla" for r in json.loads((out / "run.jsonc").read_text())["route_runs"].values())


def test_a_finished_run_is_scored_again_by_other_software_and_keeps_its_run_json(one_route_run, tmp_path):
    """Nothing is added to a finished run, so nothing mixes: it is scored again, and its
    run.json keeps naming the software that made its records."""
    out = tmp_path / "run"
    identity = _with_software(one_route_run, out, "code", "0123456789abcdef")
    code, printed = _cli([*SMOKE_ROUTE, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert "1 routes ->" in printed, printed
    assert json.loads((out / "run.jsonc").read_text()) == identity


@pytest.mark.slow
def test_a_run_without_a_record_yet_starts_again_with_other_software(half_run, tmp_path):
    """Stopped before its first route ended: no record would mix, so it runs, and its
    run.json then names the software that made all of its records."""
    out = tmp_path / "run"
    _with_software(half_run, out, "code", "0123456789abcdef")
    (out / "records.jsonl").write_text("")
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    assert code == 0, printed
    assert "2 routes ->" in printed, printed
    assert json.loads((out / "run.jsonc").read_text()) == json.loads((half_run / "run.jsonc").read_text())
    # the same for a run.json of the older layout, which names no software (no *_digest fields)
    old = tmp_path / "old"
    shutil.copytree(half_run, old)
    runs = json.loads((old / "run.jsonc").read_text())["route_runs"]
    (old / "run.jsonc").write_text(json.dumps({k: {f: v for f, v in r.items() if not f.endswith("_digest")}
                                              for k, r in runs.items()}))
    (old / "records.jsonl").write_text("")
    code, printed = _cli([*SMOKE_TWO, "--out", str(old), "--resume"])
    assert code == 0, printed
    assert "2 routes ->" in printed, printed
    assert json.loads((old / "run.jsonc").read_text()) == json.loads((half_run / "run.jsonc").read_text())


def test_resume_refuses_a_run_json_that_does_not_name_its_software(half_run, one_route_run, tmp_path):
    """A run.json of the older layout names no software: the route runs alone, at the top
    level. With a route left to run: refused; finished: scored again, its options still checked."""
    for src, name in ((half_run, "half"), (one_route_run, "done")):
        out = tmp_path / name
        shutil.copytree(src, out)
        identity = json.loads((out / "run.jsonc").read_text())
        old = {k: {f: v for f, v in r.items() if not f.endswith("_digest")} for k, r in identity["route_runs"].items()}
        (out / "run.jsonc").write_text(json.dumps(old))
    before = _tree(tmp_path / "half")
    code, printed = _cli([*SMOKE_TWO, "--out", str(tmp_path / "half"), "--resume"])
    _one_line_exit_2(code, printed, "did not record its software", "start the run afresh")
    assert _tree(tmp_path / "half") == before
    code, printed = _cli([*SMOKE_ROUTE, "--out", str(tmp_path / "done"), "--resume"])
    assert code == 0, printed
    assert "1 routes ->" in printed, printed
    code, printed = _cli([*SMOKE_ROUTE, "--seed", "3", "--out", str(tmp_path / "done"), "--resume"])
    _one_line_exit_2(code, printed, "holds another run", "seed")


@pytest.mark.parametrize("damage, words", [
    (lambda p: p.write_text(json.dumps({"software": "x", "route_runs": {}})), ["is damaged", "software entry"]),
    (lambda p: p.write_text(json.dumps({"software": None, "route_runs": {}})), ["is damaged", "software entry"]),
    (lambda p: (p.unlink(), p.mkdir()), ["is not a JSON file"]),
])
def test_resume_of_a_damaged_run_json_is_one_line(half_run, tmp_path, damage, words):
    out = tmp_path / "run"
    shutil.copytree(half_run, out)
    damage(out / "run.jsonc")
    before = _tree(out)
    code, printed = _cli([*SMOKE_TWO, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, *words)
    assert _tree(out) == before


@pytest.mark.slow
def test_resume_refuses_a_checkpoint_that_changed_under_the_same_path(tmp_path):
    """A student retrained into the same file drives otherwise: its records are another run's."""
    from model.agent import SHIPPED
    ckpt = tmp_path / "student.pt"
    shutil.copyfile(SHIPPED / "scimm" / "student.pt", ckpt)
    argv = ["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "student",
            "--agent-config", str(ckpt), "--workers", "1"]
    out = tmp_path / "run"
    code, printed = _cli([*argv, "--out", str(out)])
    assert code == 0, printed
    shutil.copyfile(SHIPPED / "fixed" / "student.pt", ckpt)  # another student, same path
    before = _tree(out)
    code, printed = _cli([*argv, "--out", str(out), "--resume"])
    _one_line_exit_2(code, printed, "holds another run", "agent_config_digest", "resume with the options")
    assert _tree(out) == before


def test_score_refuses_more_records_than_planned_routes(one_route_run, tmp_path):
    data = json.loads((one_route_run / "results.json").read_text())
    cp = data["_checkpoint"]
    cp["records"] = cp["records"] * 2  # two records, progress [1, 1]
    path = tmp_path / "merged.json"
    path.write_text(json.dumps(data))
    code, printed = _cli(["score", str(path)])
    _one_line_exit_2(code, printed, "2 records for 1 planned route runs")


def test_unwritable_outputs_are_one_line_and_leave_nothing(one_route_run, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code, printed = _cli([*SMOKE_ROUTE, "--out", str(blocker / "run")])
    _one_line_exit_2(code, printed, str(blocker))
    folder = tmp_path / "a_folder"
    folder.mkdir()
    code, printed = _cli(["score", str(one_route_run / "results.json"), "--out", str(folder)])
    _one_line_exit_2(code, printed, str(folder))
    code, printed = _cli(["report", str(one_route_run), "--out", str(blocker / "report")])
    _one_line_exit_2(code, printed, str(blocker))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "a_folder"]
    assert blocker.read_text() == "x", "the file in the way was changed"
    assert not list(folder.iterdir()), "a refused score wrote into its output folder"


def test_an_agent_that_cannot_be_built_is_bad_input(tmp_path):
    out = tmp_path / "run"
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--agent", "tests.agents:NeedsArguments",
                          "--out", str(out)])
    _one_line_exit_2(code, printed, "NeedsArguments() failed", "without arguments")
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--agent", "datetime:datetime", "--out", str(out)])
    _one_line_exit_2(code, printed, "does not subclass")
    assert not out.exists()


def test_bench_checks_its_agent_config_and_json_folder_before_running(tmp_path):
    code, printed = _cli(["bench", "--agent", "scimm", "--agent-config", str(tmp_path / "nope.pt")])
    _one_line_exit_2(code, printed, "does not exist")
    code, printed = _cli(["bench", "--json", str(tmp_path / "no" / "bench.json")])
    _one_line_exit_2(code, printed, "--json")
    code, printed = _cli(["bench", "--rounds", "0"])
    _one_line_exit_2(code, printed, "--rounds")
    (tmp_path / "rep" / "data" / "train").mkdir(parents=True)  # no data/val: not a reproduce output
    code, printed = _cli(["bench", "--arm", str(tmp_path / "rep")])
    _one_line_exit_2(code, printed, "--arm", "no data/train and data/val")
    assert [p.name for p in tmp_path.iterdir()] == ["rep"]
    assert [p.name for p in (tmp_path / "rep").iterdir()] == ["data"]


def test_report_refuses_an_unfinished_run_and_a_damaged_records_csv(one_route_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(one_route_run, run)
    res = json.loads((run / "results.json").read_text())
    (run / "results.json").write_text(json.dumps({**res, "entry_status": "Started"}))
    code, printed = _cli(["report", str(run), "--out", str(tmp_path / "report")])
    _one_line_exit_2(code, printed, "not finished")
    (run / "results.json").write_text(json.dumps(res))
    (run / "records.csv").write_text("key,ds\n0_rep0,12\n")
    code, printed = _cli(["report", str(run), "--out", str(tmp_path / "report")])
    _one_line_exit_2(code, printed, "records.csv", "KeyError")
    assert not (tmp_path / "report").exists()


def _csv_rows(path: Path) -> tuple[list[str], list[dict]]:
    import csv
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or ()), list(reader)


def _write_csv(path: Path, fields: list[str], rows: list[dict]) -> None:
    import csv
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)


@pytest.mark.parametrize("damage, words", [
    (lambda fields, rows: (fields, []), ["records.csv has no route row"]),  # once a table of nan, exit 0
    (lambda fields, rows: (fields, [{**rows[0], "ds": "nan"}]), ["row 1 ds is 'nan', not a finite number"]),
    (lambda fields, rows: (fields, [{**rows[0], "rc": "-50"}]), ["row 1 rc is '-50', outside [0, 100]"]),
    (lambda fields, rows: (fields, rows * 2), ["has 2 rows but results.json 1 records"]),
])
def test_report_refuses_a_damaged_run_folder(one_route_run, tmp_path, damage, words):
    run = tmp_path / "run"
    shutil.copytree(one_route_run, run)
    _write_csv(run / "records.csv", *damage(*_csv_rows(run / "records.csv")))
    code, printed = _cli(["report", str(run), "--out", str(tmp_path / "report")])
    _one_line_exit_2(code, printed, str(run / "records.csv"), *words, "damaged")
    assert not (tmp_path / "report").exists()


def test_report_refuses_a_results_json_with_a_number_out_of_range(one_route_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(one_route_run, run)
    data = json.loads((run / "results.json").read_text())
    data["_checkpoint"]["records"][0]["meta"]["route_length"] = -1.0
    (run / "results.json").write_text(json.dumps(data))
    code, printed = _cli(["report", str(run), "--out", str(tmp_path / "report")])
    _one_line_exit_2(code, printed, "meta.route_length is -1.0, outside [0, 1e+07]")


def test_a_checkpoint_that_is_not_a_torch_file_is_called_so(tmp_path):
    """Before, a plain-text .pt was reported as holding Python objects that could run code."""
    from model.checkpoint import load_checkpoint
    text = tmp_path / "notes.pt"
    text.write_text("hello, this is not a model\n")
    with pytest.raises(BadInput, match=r"notes.pt is not a torch file \(it starts with b'hell'\)"):
        load_checkpoint(text)
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--agent", str(text), "--out", str(tmp_path / "run")])
    _one_line_exit_2(code, printed, "is not a torch file")
    assert not (tmp_path / "run").exists()


def test_data_show_on_damaged_or_empty_datasets(tmp_path):
    episodes = tmp_path / "data" / "episodes"
    episodes.mkdir(parents=True)
    code, printed = _cli(["data", "show", str(tmp_path / "data")])
    _one_line_exit_2(code, printed, "holds no episode")
    (episodes / "0_rep0.npz").write_bytes(b"not a zip file")
    code, printed = _cli(["data", "show", str(tmp_path / "data")])
    _one_line_exit_2(code, printed, "episode file", "damaged")
    (tmp_path / "data" / "index.csv").write_text('a,b\n"1,2\n3,4,5,6\n')
    code, printed = _cli(["data", "show", str(tmp_path / "data")])
    _one_line_exit_2(code, printed, "index.csv is damaged")
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["episodes", "index.csv"]


def test_agent_may_be_a_student_checkpoint_path(tmp_path):
    """docs/design.md §3: ``--agent PATH.pt`` is the student agent with that checkpoint; a missing
    file, or a different --agent-config beside it, is one line."""
    from harness.loop.agent import check_agent
    ckpt = Path(__file__).resolve().parents[1] / "model" / "checkpoints" / "scimm" / "student.pt"
    assert check_agent(str(ckpt), None) == ("student", str(ckpt))
    assert check_agent(str(ckpt), str(ckpt)) == ("student", str(ckpt))
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--agent", str(tmp_path / "nope.pt"),
                          "--out", str(tmp_path / "run")])
    _one_line_exit_2(code, printed, "no such checkpoint file")
    other = tmp_path / "other.pt"
    other.write_bytes(ckpt.read_bytes())
    code, printed = _cli(["eval", "--routes", "town12_smoke", "--agent", str(ckpt), "--agent-config", str(other),
                          "--out", str(tmp_path / "run")])
    _one_line_exit_2(code, printed, "is a checkpoint: drop --agent-config")
    assert not (tmp_path / "run").exists()


def test_render_draws_the_waypoint_overlay_of_eval_runs(one_route_run, tmp_path):
    """docs/design.md §9: render makes a video or the Fig. 5 overlay (--runs); the overlay's bad inputs
    are one line and write nothing."""
    out = tmp_path / "fig5.png"
    code, printed = _cli(["render", "--route", "0", "--runs", str(one_route_run), "--out", str(out)])
    assert code == 0, printed
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", printed
    for argv, words in ((["--route", "1", "--runs", str(one_route_run), "--out", str(tmp_path / "b.png")],
                         ["no log of route 1"]),
                        (["--route", "0", "--runs", str(one_route_run), "--out", str(tmp_path / "b.mp4")],
                         ["must end in .png"]),
                        (["--route", "0", "--out", str(tmp_path / "b.mp4")], ["needs --routes SET"])):
        code, printed = _cli(["render", *argv])
        _one_line_exit_2(code, printed, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig5.png"]


def test_score_reads_a_gzip_compressed_results_file_and_refuses_a_damaged_one(one_route_run, tmp_path):
    """The experiment's records are kept gzip-compressed (files.compressed): score reads
    them as it reads the plain file, into a folder it creates; a cut-short .gz is one line."""
    from files.compressed import gzip_copy
    packed = tmp_path / "results.json.gz"
    gzip_copy(one_route_run / "results.json", packed)
    assert _cli(["score", str(one_route_run / "results.json"), "--out", str(tmp_path / "plain.json")])[0] == 0
    assert _cli(["score", str(packed), "--out", str(tmp_path / "new" / "packed.json")])[0] == 0
    assert (tmp_path / "new" / "packed.json").read_text() == (tmp_path / "plain.json").read_text()
    cut = tmp_path / "cut.json.gz"
    cut.write_bytes(packed.read_bytes()[:60])
    code, printed = _cli(["score", str(cut)])
    _one_line_exit_2(code, printed, "not a readable gzip file")


def test_a_closed_output_pipe_is_named_as_such():
    from sumo_scimm.cli import _os_error
    line = _os_error(BrokenPipeError(32, "Broken pipe"))
    assert line == "Broken pipe (the program reading the output closed it first)"
