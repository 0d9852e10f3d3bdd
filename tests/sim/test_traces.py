from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sdit_path.reading.recording import TraceError, read_trace

from conftest import DATA


def _write(tmp_path, text: str):
    p = tmp_path / "t.csv"
    p.write_text(text)
    return p


def test_forgiving_where_the_contract_allows(tmp_path):
    rest = "".join(f"v,0.0002,{k / 1000:.3f}\n" for k in range(4, 200))
    p = _write(tmp_path, "# sample_rate_hz: 1000\n# bar_length_mm: 150\nfoo,delta_l_mm,t_s\n"
                         "x,0.001,0.0\ny,,0.001\nz,nan,0.002\nw,-0.0005,0.003\n" + rest)
    tr = read_trace(p)
    assert tr.header["sample_rate_hz"] == "1000"
    assert np.allclose(tr.t_s[:4], [0, 0.001, 0.002, 0.003]) and len(tr.t_s) == 200
    assert tr.delta_l_um[0] == pytest.approx(1.0) and tr.delta_l_um[3] == pytest.approx(-0.5)
    assert np.isnan(tr.delta_l_um[1]) and np.isnan(tr.delta_l_um[2])


@pytest.mark.parametrize("text,expected", [
    ("t_s,value\n0,1\n", "t.csv:1: header row 't_s,value' lacks t_s and delta_l_um"),
    ("t_s,delta_l_um\n0,1\n0.001,abc\n", "t.csv:3: delta_l_um 'abc' is not a number"),
    ("t_s,delta_l_um\n0,1\n0.002,1\n0.001,1\n", "t.csv:4: time goes backwards"),
    ("t_s,delta_l_um,segment\n0,1,A1-1\n0.001,2\n", "t.csv:3: 2 fields, expected 3 (truncated"),
    ("# only a comment\n", "no header row"),
    ("t_s,delta_l_um\n", "no data rows"),
])
def test_bad_traces_name_the_line(tmp_path, text, expected):
    with pytest.raises(TraceError) as err:
        read_trace(_write(tmp_path, text))
    assert expected in str(err.value)


@pytest.mark.slow
def test_simulate_then_identify_from_the_cli(tmp_path):
    plan_dir = tmp_path / "plan"

    def run(*args):
        return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                              text=True, timeout=600)

    assert run("plan", str(DATA / "golden_small.toml"), "--out", str(plan_dir), "-q").returncode == 0
    trace = tmp_path / "a.csv"
    r = run("simulate", "--plan", str(plan_dir), "--program", "GOLD_A", "--errors",
            "paper_table2", "--noise-um", "0.2", "--out", str(trace))
    assert r.returncode == 0, r.stderr
    assert "# program: GOLD_A" in trace.read_text()
    r = run("identify", "--plan", str(plan_dir), "--trace", str(trace), "--no-squareness",
            "--json", str(tmp_path / "id.json"))
    assert r.returncode == 0, r.stderr
    assert "What the data determine" in r.stdout and "ball centring" in r.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,delta_l_um\n0,1\n0.001,oops\n")
    r = run("identify", "--plan", str(plan_dir), "--trace", str(bad), "--program", "GOLD_A")
    assert r.returncode == 2 and "bad.csv:3: delta_l_um 'oops' is not a number" in r.stderr
    assert "Traceback" not in r.stderr
    r = run("simulate", "--plan", str(plan_dir), "--program", "NOPE", "--errors", "paper_table2",
            "--out", str(tmp_path / "x.csv"))
    assert r.returncode == 2 and "no program 'NOPE'; programs: GOLD_A, GOLD_B" in r.stderr
