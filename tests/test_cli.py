from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sdit_path.config import sample_path

from conftest import edit


def run(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def tree(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def planned(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plan") / "out"
    r = run("plan", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.slow
def test_plan_writes_layer_programs_and_manifest(planned):
    files = set(tree(planned))
    for layer in "ABCDE":
        assert f"sinumerik840d/SDIT_{layer}.MPF" in files
        assert f"linuxcnc/SDIT_{layer}.ngc" in files
    m = json.loads((planned / "plan.json").read_text())
    assert m["sphere"] == {"centre_mm": [0.0, 0.0, 50.0], "radius_mm": 150.0}
    assert [t["name"] for t in m["tracks"]] == list("ABCDE")
    assert len(m["nodes"]) == 31 and all(n["dwell_s"] == 2.0 for n in m["nodes"])
    assert len(m["segments"]) == 90
    seg = next(s for s in m["segments"] if s["id"] == "D3-2")
    assert (seg["layer"], seg["sector"], seg["subsegment"]) == ("D", 3, 2)
    assert seg["feed_mm_per_min"] == 600.0 and seg["length_mm"] > 10
    assert 0 < seg["max_radial_deviation_um"]["sinumerik840d"] <= 0.01
    assert 0 < seg["max_radial_deviation_um"]["linuxcnc"] <= 0.1
    progs = {p["file"]: p for p in m["programs"]}
    d = progs["sinumerik840d/SDIT_D.MPF"]
    assert d["layer"] == "D" and d["controller"] == "sinumerik840d"
    assert d["segment_order"][:3] == ["D1-1", "D1-2", "D1-3"] and len(d["segment_order"]) == 36
    assert d["frame"]["work_offset"] == "G54"
    assert m["summary"]["sinumerik840d"]["max_radial_deviation_um"] <= 0.01


@pytest.mark.slow
def test_same_input_gives_byte_identical_output(planned, tmp_path):
    again = tmp_path / "again"
    assert run("plan", "--out", str(again), "-q").returncode == 0
    assert tree(again) == tree(planned)


@pytest.mark.slow
def test_refuses_non_empty_dir_and_force_never_deletes_foreign_files(tmp_path, planned):
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    (out / "keep.txt").write_text("mine")
    (out / "sub" / "data.csv").write_text("1,2")
    r = run("plan", "--out", str(out))
    assert r.returncode == 5
    assert "not empty; pass --force" in r.stderr and "Traceback" not in r.stderr
    r = run("plan", "--out", str(out), "--force", "-q")
    assert r.returncode == 5 and "holds keep.txt, which sdit-path plan did not write" in r.stderr
    assert tree(out) == {"keep.txt": b"mine", "sub/data.csv": b"1,2"}
    # an earlier plan output is replaced as a whole, with no hidden leftovers
    (out / "keep.txt").unlink()
    (out / "sub" / "data.csv").unlink()
    (out / "sub").rmdir()
    assert run("plan", "--out", str(out), "-q").returncode == 0
    assert run("plan", "--out", str(out), "--force", "-q").returncode == 0
    assert tree(out) == tree(planned)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]
    # a user's file added to a plan output is not deleted either
    (out / "notes.txt").write_text("mine")
    r = run("plan", "--out", str(out), "--force", "-q")
    assert r.returncode == 5 and "holds notes.txt" in r.stderr
    assert (out / "notes.txt").read_text() == "mine"
    # preview refuses to replace a plan
    (out / "notes.txt").unlink()
    r = run("preview", "--out", str(out), "--force", "-q")
    assert r.returncode == 5 and "holds an output of sdit-path plan; --force replaces only " \
        "an earlier preview output" in r.stderr
    assert (out / "plan.json").is_file()


@pytest.mark.slow
def test_force_never_replaces_the_working_folder_or_the_configs(tmp_path):
    cfg = tmp_path / "cfgdir" / "m.toml"
    cfg.parent.mkdir()
    cfg.write_text(sample_path("vmc_3axis.toml").read_text())
    for out, cwd in ((".", tmp_path), ("..", tmp_path / "cfgdir"), (str(cfg.parent), tmp_path)):
        r = run("plan", str(cfg), "--out", out, "--force", "-q", cwd=cwd)
        assert r.returncode == 5 and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    assert cfg.is_file()


@pytest.mark.slow
def test_outputs_respect_the_umask(tmp_path):
    import os
    import stat

    script = ("import os, sys; os.umask(0o022); from sdit_path.cli import main; "
              "sys.argv = ['sdit-path'] + sys.argv[1:]; main()")
    plan_dir = tmp_path / "p"
    r = subprocess.run([sys.executable, "-c", script, "plan", "--out", str(plan_dir), "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-c", script, "simulate", "--plan", str(plan_dir),
                        "--program", "SDIT_E", "--errors", "paper_table2", "--out",
                        str(tmp_path / "t.csv")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    for p in [plan_dir, *plan_dir.rglob("*"), tmp_path / "t.csv"]:
        mode = stat.S_IMODE(os.stat(p).st_mode)
        assert mode == (0o755 if p.is_dir() else 0o644), (p, oct(mode))


@pytest.mark.slow
def test_no_terminal_prints_a_line_per_stage(tmp_path):
    r = run("plan", "--out", str(tmp_path / "p"))
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[0] == "sdit-path: planning"
    assert any("[1/" in ln and "layer A planned and checked" in ln for ln in lines)
    assert len(lines) >= 10


@pytest.mark.parametrize("key,value,code,expected", [
    ("bar_length_mm", "0.0", 2, "ballbar.bar_length_mm: expected a value > 0"),
    ("controllers", '["fanuc31"]', 2, "known controllers: fanuc, fanuc_nurbs, haas, heidenhain, linuxcnc"),
    ("feed_mm_per_min", "0", 2, "test.feed_mm_per_min: expected a value > 0"),
])
def test_bad_input_is_one_line_without_traceback(tmp_path, key, value, code, expected):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(edit(sample_path("vmc_3axis.toml").read_text(), key, value))
    out = tmp_path / "out"
    r = run("plan", str(cfg), "--out", str(out))
    assert r.returncode == code
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], r.stderr
    assert r.stderr == lines[0] + "\n"
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_unreachable_plan_names_segment_axis_and_overshoot(tmp_path):
    cfg = tmp_path / "far.toml"
    cfg.write_text(edit(sample_path("vmc_3axis.toml").read_text(), "pivot_mm", "[300.0, 0.0, 50.0]"))
    out = tmp_path / "o"
    r = run("plan", str(cfg), "--out", str(out), "-q")
    assert r.returncode == 3 and "Traceback" not in r.stderr
    lines = r.stderr.splitlines()
    assert lines[0].startswith("sdit-path: error: ") and "infeasible piece(s): A1-1" in lines[0]
    assert "--skip-infeasible" in lines[0]
    assert "  layer A, A1-1: X 450.000 mm exceeds its limit 400 mm by 50.000 mm at ball " \
           "(450.000, 0.000, 50.000) mm" in lines
    assert not out.exists()


def test_unparseable_config_names_file_and_line(tmp_path):
    cfg = tmp_path / "broken.toml"
    cfg.write_text("[machine]\nname = \"x\"\naxes = {\n")
    r = run("plan", str(cfg), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and f"{cfg}:3" in r.stderr and "cannot parse TOML" in r.stderr


@pytest.mark.slow
def test_user_text_cannot_inject_blocks(tmp_path):
    text = sample_path("vmc_3axis.toml").read_text()
    text = edit(text, "program_prefix", '"X\\nG0 Z-500\\r;"')
    text = text.replace('work_offset = "G54"',
                        'work_offset = "G54"\ncomment = "note\\nG0 X-999 Z-999\\u2028M0 ) (MSG, boom"')
    text = text.replace('name = "VMC 3-axis, 150 mm ballbar"', 'name = "VMC\\nM00"')
    cfg = tmp_path / "inject.toml"
    cfg.write_text(text)
    out = tmp_path / "o"
    r = run("plan", str(cfg), "--out", str(out), "-q")
    assert r.returncode == 0, r.stderr
    for name, data in tree(out).items():
        if not name.endswith((".MPF", ".ngc")):
            continue  # plan.json and the copied config.toml hold the text as data
        lines = data.decode("ascii").splitlines()
        assert not any(l.startswith("G0") for l in lines), name
        # the only stops are ours (the operator sequence's), each after its message
        for k, line in enumerate(lines):
            if line.startswith("M0"):
                assert line == "M0" and lines[k - 1].startswith(("(STOP: ", "; STOP: ")), name
        assert not any("X-999" in l and not l.startswith((";", "(")) for l in lines)
        assert all(l.count("(") == l.count(")") <= 1 for l in lines if l.startswith("("))
    assert (out / "sinumerik840d" / "X_G0_Z_500___A.MPF").exists()


def test_version_and_help():
    r = run("--version")
    assert r.returncode == 0 and "sdit-path" in r.stdout
    r = run("plan", "--help")
    assert r.returncode == 0 and "--force" in r.stdout
