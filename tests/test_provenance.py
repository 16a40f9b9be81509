"""The software a run records (harness.runs.provenance): the code digest covers the stages' files
that can change a record, wherever they are installed; the versions are the installed ones;
agents' checkpoints and modules are identified by their bytes."""
from __future__ import annotations

import re

from harness.runs import provenance


def test_the_code_digest_follows_sources_nets_and_checkpoints_only(tmp_path, monkeypatch):
    roots = {name: tmp_path / name for name in provenance.PACKAGES}
    for root in roots.values():
        (root / "sub").mkdir(parents=True)
        (root / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(provenance, "_package_dir", lambda name: roots[name])
    base = provenance.code_digest()
    assert re.fullmatch(r"[0-9a-f]{16}", base)
    # files that cannot change a record: docs, bytecode
    (roots["harness"] / "notes.md").write_text("words")
    (roots["harness"] / "__pycache__").mkdir()
    (roots["harness"] / "__pycache__" / "a.cpython-311.py").write_text("cached")
    assert provenance.code_digest() == base
    # each kind that can, anywhere in a stage's tree, and a file's place as well as its bytes
    for path, text in ((roots["model"] / "sub" / "student.pt", "weights"), (roots["sumo_nets"] / "t.net.xml", "<net/>"),
                       (roots["harness"] / "a.py", "x = 2\n")):
        before = provenance.code_digest()
        path.write_text(text)
        assert provenance.code_digest() != before, path
    before = provenance.code_digest()
    (roots["scimm"] / "a.py").rename(roots["scimm"] / "sub" / "a.py")
    assert provenance.code_digest() != before


def test_the_code_digest_does_not_depend_on_where_the_stages_are_installed(tmp_path, monkeypatch):
    trees = {}
    for where in ("clone_a", "elsewhere/clone_b"):
        roots = {name: tmp_path / where / name for name in provenance.PACKAGES}
        for name, root in roots.items():
            (root / "nets").mkdir(parents=True)
            (root / "a.py").write_text(f"NAME = {name!r}\n")
            (root / "nets" / "t.net.xml").write_text("<net/>")
        trees[where] = roots
    digests = []
    for roots in trees.values():
        monkeypatch.setattr(provenance, "_package_dir", lambda name, roots=roots: roots[name])
        digests.append(provenance.code_digest())
    assert digests[0] == digests[1]


def test_software_names_the_python_and_the_pinned_libraries():
    sw = provenance.software()
    assert re.fullmatch(r"[0-9a-f]{16}", sw["code"])
    assert sw["python"].count(".") == 2
    assert set(provenance.LIBRARIES) <= set(sw)
    assert all(sw[lib] for lib in provenance.LIBRARIES), sw
    # the pins of pyproject.toml (libsumo and sumolib with eclipse-sumo, the runtime)
    assert sw["libsumo"] == sw["sumolib"] == "1.28.0"
    assert sw["onnxruntime"] == "1.32.0"


def test_a_config_digest_is_of_the_bytes_and_follows_a_rewrite(tmp_path):
    f, g = tmp_path / "student.pt", tmp_path / "other_name.pt"
    f.write_bytes(b"one")
    g.write_bytes(b"one")
    one = provenance.config_digest(str(f))
    assert one == provenance.config_digest(str(g))  # the bytes, not the name
    f.write_bytes(b"two")  # same size: read again all the same (another change time)
    assert provenance.config_digest(str(f)) not in (one, None)
    assert provenance.config_digest(str(tmp_path / "missing.pt")) is None


def test_a_module_agent_is_identified_by_its_module_file(tmp_path, monkeypatch):
    """An agent given as module:Class lives outside the stages: its file's digest is part
    of each route run, so editing it is another run."""
    from harness.runs.jobs import Job
    from scenarios import set_path
    from scenarios.routefile import read_routes
    (tmp_path / "my_agent.py").write_text("class A: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    route = read_routes(set_path("town12_smoke"))[1][0]
    job = Job(0, route, 0, "my_agent:A", None, 1, str(tmp_path))
    before = provenance.run_identity([job])["route_runs"][job.key]["agent_module_digest"]
    (tmp_path / "my_agent.py").write_text("class A:\n    speed = 2\n")
    after = provenance.run_identity([job])["route_runs"][job.key]["agent_module_digest"]
    assert before, "no digest before the edit"
    assert after, "no digest after the edit"
    assert before != after
    assert "agent_module_digest" not in provenance.run_identity([Job(0, route, 0, "expert", None, 1, "")])["route_runs"][job.key]


# a processor's block of /proc/cpuinfo as a KVM guest prints it (shortened); the kernel
# prints one per CPU, here two
BLOCK = """processor\t: {}
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
stepping\t: 1
flags\t\t: fpu sse2 avx avx2 avx512f avx512bw
"""
CPUINFO = BLOCK.format(0) + "\n" + BLOCK.format(1)


def test_the_cpu_is_named_by_model_name_id_and_widest_vector_extension():
    assert provenance.cpu_of(CPUINFO) == {"cpu": "AMD EPYC", "cpu_id": "25/17/1", "simd": "AVX-512"}
    no512 = CPUINFO.replace(" avx512f avx512bw", "")
    assert provenance.cpu_of(no512)["simd"] == "AVX2"
    assert provenance.cpu_of(no512.replace(" avx2", ""))["simd"] == "other"
    # an ARM kernel prints no family or model name: no id, the platform's name
    arm = provenance.cpu_of("processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd\n")
    assert arm["cpu_id"] is None and arm["simd"] == "other" and arm["cpu"]
    here = provenance.machine()
    assert here["cores"] >= 1 and set(here) == {"cpu", "cpu_id", "simd", "cores"}
