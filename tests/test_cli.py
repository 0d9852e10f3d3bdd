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


def test_same_input_gives_byte_identical_output(planned, tmp_path):
    again = tmp_path / "again"
    assert run("plan", "--out", str(again), "-q").returncode == 0
    assert tree(again) == tree(planned)


def test_refuses_non_empty_dir_and_force_replaces(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    r = run("plan", "--out", str(out))
    assert r.returncode == 5
    assert "not empty; pass --force" in r.stderr and "Traceback" not in r.stderr
    assert tree(out) == {"keep.txt": b"mine"}
    r = run("plan", "--out", str(out), "--force", "-q")
    assert r.returncode == 0, r.stderr
    assert "keep.txt" not in tree(out) and "plan.json" in tree(out)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


@pytest.mark.parametrize("key,value,code,expected", [
    ("bar_length_mm", "0.0", 2, "ballbar.bar_length_mm: expected a value > 0"),
    ("controllers", '["fanuc31"]', 2, "known controllers: linuxcnc, sinumerik840d"),
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
    r = run("plan", str(cfg), "--out", str(out))
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
        assert not any(l.startswith(("G0", "M0")) for l in lines), name
        assert not any("X-999" in l and not l.startswith((";", "(")) for l in lines)
        assert all(l.count("(") == l.count(")") <= 1 for l in lines if l.startswith("("))
    assert (out / "sinumerik840d" / "X_G0_Z_500___A.MPF").exists()


def test_version_and_help():
    r = run("--version")
    assert r.returncode == 0 and "sdit-path" in r.stdout
    r = run("plan", "--help")
    assert r.returncode == 0 and "--force" in r.stdout
