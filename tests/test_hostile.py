"""Hostile and realistic input: bounds on every config number, user text that a
controller would act on, spreadsheet exports of recordings, edited plan directories,
kills in the middle of a write, a full disk, and seeded fuzzing of the config loader
and the recording reader.  Nothing may end in a traceback, a hang, a lost user file or
a silent wrong success."""

from __future__ import annotations

import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from sdit_path.config import sample_path
from sdit_path.errors import ConfigError, SditError
from sdit_path.output import MARKER, write_file, write_tree
from sdit_path.plan.configure import parse_config
from sdit_path.plan.files import load_plan
from sdit_path.reading.recording import read_trace

from conftest import DATA, edit, have_linuxcnc
from hostile_cases import PLAN_EDITS
from mutate import mutate_config, mutate_trace

SMALL = DATA / "golden_small.toml"


def run(*args, cwd=None, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


def tree(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def one_error_line(r: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in r.stderr, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("sdit-path: error:")]
    assert len(errors) == 1, r.stderr
    assert len(errors[0]) < 400, errors[0]
    return errors[0]


# --------------------------------------------------------------------------- config bounds

BASE3 = sample_path("vmc_3axis.toml").read_text()
BASE5 = sample_path("bc_table_5axis.toml").read_text()


@pytest.mark.parametrize("text,key,expected", [
    (edit(BASE3, "pose_spacing_mm", "1e-6"), "check.pose_spacing_mm", ">= 0.05 mm"),
    (edit(BASE3, "pose_spacing_mm", "5e-324"), "check.pose_spacing_mm", ">= 0.05 mm"),
    (edit(BASE3, "track_elevations_deg", "[0.0, 1e-12]"), "test.track_elevations_deg",
     "at least 1 deg apart"),
    (edit(BASE3, "max_velocity_mm_per_s", "1e300"), "machine.axes.X.max_velocity_mm_per_s",
     "<= 20000 mm/s"),
    (edit(BASE3, "max_jerk_mm_per_s3", "1e-9"), "machine.axes.X.max_jerk_mm_per_s3",
     ">= 10 mm/s^3"),
    (BASE3 + "\n[timing]\nsample_rate_hz = 20000\n", "timing.sample_rate_hz", "<= 5000 Hz"),
    (BASE3 + "\n[timing]\nsample_rate_hz = 1e-3\n", "timing.sample_rate_hz", ">= 10 Hz"),
    (edit(BASE3, "feed_mm_per_min", "1e-300"), "test.feed_mm_per_min", "at least 1 mm/min"),
    (edit(BASE3, "work_offset", '"G54.1 P99999999999999999999"'), "post.work_offset",
     "G54.1 P1..P300"),
    (edit(BASE3, "travel_mm", "[-1e308, 1e308]"), "machine.axes.X.travel_mm", "+-100000"),
    (edit(BASE3, "size_mm", "[1e300, 1e300, 1e300]"), "scene.parts[0].size_mm", "+-10000"),
    (edit(BASE3, "position_mm", "[0, 0, -9.2e18]"), "scene.parts[0].position_mm", "+-10000"),
    (edit(BASE5, "point_mm", "[1e300, 0, -250]"), "machine.axes.B.point_mm", "+-10000"),
    (edit(BASE5, "direction", "[3, 0, 1]", "machine.axes.C"), "machine.axes.C.direction",
     "within 60 deg of Z"),
    (edit(BASE3, "name", '"' + "x" * 100_000 + '"'), "machine.name", "at most 1000 characters"),
    (edit(BASE3, "tool_length_mm", "1e9"), "machine.tool_length_mm", "<= 2000 mm"),
    (edit(BASE3, "spline_tolerance_um", "1e-300"), "post.spline_tolerance_um", ">= 0.001 um"),
    (edit(BASE3, "dwell_s", "1e-300"), "test.dwell_s", ">= 0.1 s"),
])
def test_implausible_numbers_are_refused_with_the_bound(text, key, expected):
    with pytest.raises(ConfigError) as err:
        parse_config(text, "x.toml")
    msg = str(err.value)
    assert key in msg and expected in msg, msg
    assert re.match(r"x\.toml:\d+: ", msg), msg  # file and line
    assert "\n" not in msg and len(msg) < 400


def test_a_config_with_a_byte_order_mark_is_read(tmp_path):
    """Notepad writes a UTF-8 byte-order mark: the config reads as without it."""
    from sdit_path.plan.configure import load_config

    p = tmp_path / "bom.toml"
    p.write_bytes(b"\xef\xbb\xbf" + BASE3.encode("utf-8"))
    assert load_config(str(p)).machine == parse_config(BASE3, "x.toml").machine


def test_a_reading_no_ballbar_gives_is_refused_by_its_line(tmp_path):
    text = _trace_text().splitlines()
    k = next(i for i, ln in enumerate(text) if ln and ln[0].isdigit()) + 7
    t, _ = text[k].split(",")[:2]
    text[k] = f"{t},1e308"
    p = tmp_path / "big.csv"
    p.write_text("\n".join(text) + "\n")
    with pytest.raises(SditError) as err:
        read_trace(p)
    assert f"big.csv:{k + 1}:" in str(err.value) and "a ballbar reads within" in str(err.value)
    assert err.value.exit_code == 2


def test_a_spindle_nose_a_kilometre_long_is_refused():
    text = BASE3.replace("size_mm = [50.0, 150.0]", "size_mm = [50.0, 1e6]")
    assert text != BASE3
    with pytest.raises(ConfigError, match=r"size_mm: expected values within \+-10000"):
        parse_config(text, "x.toml")


# --------------------------------------------------------------------------- bundled names

@pytest.mark.slow
def test_a_path_is_never_taken_for_a_bundled_sample(tmp_path):
    r = run("plan", "./vmc_3axis.toml", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and "no such file" in one_error_line(r)
    r = run("plan", "vmc_3axis.toml", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and not (tmp_path / "o").exists()
    r = run("plan", "sub/vmc_3axis", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2


# --------------------------------------------------------------------------- NC safety

#: What LinuxCNC 2.9 acts on in a comment: rs274ngc's convert_comment skips leading
#: white space and compares in lower case; the Python plug-in adds py, pyrun, pyreload;
#: AXIS reads "AXIS," comments.
ACTING = ("msg,", "debug,", "print,", "log", "probe", "abort,", "py,", "pyrun,", "pyreload",
          "axis,")


def linuxcnc_acts_on(comment: str) -> bool:
    return comment.lstrip(" \t").lower().startswith(ACTING)


@pytest.mark.slow
@pytest.mark.oracle
def test_user_text_never_reaches_a_controller_as_something_it_acts_on(tmp_path):
    text = SMALL.read_text(encoding="utf-8")
    text = "# Fräsmaschine, Prüfstand 3\n" + text
    text = re.sub(r'(?m)^name = ".*"$', 'name = "中文 Fräse ' + "x" * 300 + '"', text, count=1)
    text = re.sub(r'(?m)^program_prefix = .*$', 'program_prefix = "PYRELOAD"', text, count=1)
    assert "PYRELOAD" in text
    payloads = ["PY,import os", "\ufeffpy,import os", "\u00a0pyrun,os.system('x')",
                "\u200bPyReload", "  msg,hi", "DEBUG,#<_x>", "LogOpen,/tmp/x", "probeopen x",
                "AXIS,stop", "ABORT,now"]
    cfg_dir = tmp_path / "cfg"
    cfg_dir.mkdir()
    for k in range(0, len(payloads), 2):  # two payloads a plan: the comment and the name
        payload = payloads[k]
        t = text.replace("[post]", f"[post]\ncomment = {json.dumps(payload)}", 1)
        t = t.replace('name = "中文 Fräse ', 'name = ' + json.dumps("中文 Fräse " + payloads[k + 1])[:-1]
                      + " ", 1)
        cfg = cfg_dir / f"p{k}.toml"
        cfg.write_text(t, encoding="utf-8")
        out = tmp_path / f"o{k}"
        r = run("plan", str(cfg), "--out", str(out), "-q")
        assert r.returncode == 0, r.stderr
        for name, data in tree(out).items():
            if name.endswith(".ngc"):
                for line in data.decode("ascii").splitlines():
                    assert len(line) <= 250, (name, len(line))
                    for c in re.findall(r"\(([^)]*)\)", line):
                        assert not linuxcnc_acts_on(c), (payload, line)
            elif name.endswith(".MPF"):
                assert all(len(ln) <= 512 for ln in data.decode("ascii").splitlines())
        if have_linuxcnc():  # LinuxCNC's own interpreter runs it and shows nothing
            from linuxcnc_oracle import interpret, ok

            result, message, rec = interpret(str(out / "linuxcnc" / "PYRELOAD_A.ngc"))
            assert ok(result), message
            assert rec.messages == [] and len(rec.feeds) > 100
        if k == 0:  # user text kept as data where nothing acts on it
            manifest = json.loads((out / "plan.json").read_text(encoding="utf-8"))
            assert manifest["machine"].startswith("中文 Fräse")
            assert (out / "config.toml").read_text(encoding="utf-8") == t


def test_lints_refuse_acting_comments_long_lines_and_zero_feed():
    from sdit_path.nc.registry import get_postprocessor

    lcnc = get_postprocessor("linuxcnc")
    ok = "%\nG21 G17 G90 G94 G40\nG54\nG1 X1 Y1 Z1 F100\nM2\n%\n"
    assert lcnc.lint(ok, {}) == []
    for bad, what in [("(py,import os)", "special comment"), ("(  PyRun,x)", "special comment"),
                      ("(pyreload)", "special comment"), ("(AXIS,stop)", "special comment"),
                      ("(" + "x" * 260 + ")", "characters"), ("G1 X2 F0", "feed must be > 0"),
                      ("G1 X2 F-5", "feed must be > 0")]:
        problems = lcnc.lint(ok.replace("M2\n", bad + "\nM2\n"), {})
        assert any(what in p for p in problems), (bad, problems)
    sin = get_postprocessor("sinumerik840d")
    good = "G17 G90 G71 G94 G40 G54\nM5\nG1 X1 Y1 Z1 F100\nM30\n"
    assert sin.lint(good, {}) == []
    assert any("must be > 0" in p for p in sin.lint(good.replace("F100", "F0"), {}))


# --------------------------------------------------------------------------- recordings

def _trace_text(n=2000, sep=",", decimal=".", quote=False) -> str:
    t = np.arange(n) / 1000.0
    y = 3.0 * np.sin(t)
    head = ["t_s", "delta_l_um"]
    if quote:
        head = [f'"{h}"' for h in head]
    rows = [sep.join(head)]
    for a, b in zip(t, y):
        rows.append(sep.join((f"{a:.4f}".replace(".", decimal), f"{b:.4f}".replace(".", decimal))))
    return "# sample_rate_hz: 1000\n" + "\n".join(rows) + "\n"


def test_spreadsheet_exports_are_read_when_unambiguous(tmp_path):
    ref = tmp_path / "ref.csv"
    ref.write_text(_trace_text())
    want = read_trace(ref)
    for k, text in enumerate([_trace_text(sep=";", decimal=","), _trace_text(sep="\t"),
                              _trace_text(sep="\t", decimal=","), _trace_text(quote=True),
                              _trace_text(sep=";", decimal=",", quote=True)]):
        p = tmp_path / f"x{k}.csv"
        p.write_text(text)
        got = read_trace(p)
        np.testing.assert_array_equal(got.t_s, want.t_s)
        np.testing.assert_array_equal(got.delta_l_um, want.delta_l_um)
    p = tmp_path / "ambiguous.csv"
    p.write_text(_trace_text(sep=",", decimal=","))
    with pytest.raises(SditError, match=r"separate the columns with ';'"):
        read_trace(p)


@pytest.mark.parametrize("mutate,expected", [
    (lambda t: "\n".join(t.splitlines()[:3]) + "\n", "reading(s) that are numbers"),
    (lambda t: re.sub(r"(?m),[-0-9.]+$", ",nan", t), "reading(s) that are numbers"),
    (lambda t: re.sub(r"(?m)^(\d+)\.(\d+),", lambda m: f"{float(m.group(0)[:-1]) * 1000:.1f},",
                      t), "milliseconds"),
    (lambda t: re.sub(r"(?m)^(\d+\.\d+),", lambda m: f"{1.7e9 + float(m.group(1)):.4f},", t),
     "epoch"),
    (lambda t: t.replace("0.0005,", "0.0005," + "9" * 5_000_000 + "x", 1)
     if "0.0005," in t else t.replace("\n0.0010,", "\n0.0010,x" + "9" * 5_000_000, 1),
     "is not a number"),
])
def test_recordings_that_are_not_what_they_claim_are_refused(tmp_path, mutate, expected):
    p = tmp_path / "m.csv"
    p.write_text(mutate(_trace_text()))
    with pytest.raises(SditError) as err:
        read_trace(p)
    msg = str(err.value)
    assert expected in msg and len(msg) < 400, msg[:500]


# --------------------------------------------------------------------------- plan directories

@pytest.fixture(scope="module")
def small_plan(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("hostile") / "plan"
    r = run("plan", str(SMALL), "--out", str(out), "-q")
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.parametrize("name", sorted(PLAN_EDITS))
@pytest.mark.slow
def test_edited_plan_directories_are_refused_by_name(small_plan, tmp_path, name):
    edit_fn, expected = PLAN_EDITS[name]
    d = tmp_path / "plan"
    shutil.copytree(small_plan, d)
    edit_fn(d)
    # one line: no library warning printed before it (pandas warned of mixed types in a
    # column holding "nan" before the error named it)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(SditError) as err:
            plan = load_plan(d)
            for prog in plan.program_names:
                plan.trajectory(prog)
            if name == "cut to 10 rows":
                from sdit_path.sim.simulate import simulate_trace
                from sdit_path.errormodel.errorset import load_error_set
                simulate_trace(plan, "GOLD_A", load_error_set("paper_table2"), (0, 0, 0), 0, 0,
                               0.1, 0)
                raise AssertionError("a trajectory cut to 10 rows was read as the program")
    if expected:
        assert expected in str(err.value), str(err.value)
    assert "\n" not in str(err.value)
    assert not caught, [str(w.message) for w in caught]


@pytest.mark.slow
def test_commands_reading_an_edited_plan_end_with_one_line(small_plan, tmp_path):
    d = tmp_path / "plan"
    shutil.copytree(small_plan, d)
    PLAN_EDITS["tested_travel missing"][0](d)
    trace = tmp_path / "t.csv"
    trace.write_text(_trace_text())
    for args in (["simulate", "--plan", str(d), "--program", "GOLD_A", "--errors", "paper_table2",
                  "--out", str(tmp_path / "s.csv")],
                 ["identify", "--plan", str(d), "--trace", str(trace), "--program", "GOLD_A"],
                 ["diagnose", "--plan", str(d), "--program", "GOLD_A", "--measured", str(trace)]):
        r = run(*args)
        assert r.returncode == 2, r.stderr
        assert "tested_travel" in one_error_line(r)


@pytest.mark.slow
def test_identify_refuses_a_recording_of_part_of_the_program(small_plan, tmp_path):
    full = tmp_path / "full.csv"
    r = run("simulate", "--plan", str(small_plan), "--program", "GOLD_A", "--errors",
            "paper_table2", "--noise-um", "0.2", "--out", str(full))
    assert r.returncode == 0, r.stderr
    lines = full.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    part = tmp_path / "part.csv"
    part.write_text("\n".join(head + body[: len(body) // 10]) + "\n")
    r = run("identify", "--plan", str(small_plan), "--trace", str(part))
    assert r.returncode == 6 and "not a recording of GOLD_A" in one_error_line(r), r.stderr
    assert "determined" not in r.stdout


# --------------------------------------------------------------------------- writes

@pytest.mark.slow
def test_kills_leave_the_old_or_the_new_output_whole(tmp_path):
    """SIGKILL `plan --force` at seeded moments: the output is always a whole plan (the
    old one or the new one, never a mixture or nothing), and the next run leaves no
    hidden leftovers."""
    out = tmp_path / "out"
    r = run("plan", str(SMALL), "--out", str(out), "-q")
    assert r.returncode == 0
    reference = tree(out)
    other = tmp_path / "other.toml"
    other.write_text(SMALL.read_text().replace("feed_mm_per_min = 1000.0",
                                               "feed_mm_per_min = 800.0"))
    t0 = time.perf_counter()
    assert run("plan", str(other), "--out", str(tmp_path / "ref2"), "-q").returncode == 0
    duration = time.perf_counter() - t0
    reference2 = tree(tmp_path / "ref2")
    rng = random.Random(14)
    outcomes = set()
    for k in range(8):
        cfg = other if k % 2 == 0 else SMALL
        proc = subprocess.Popen([sys.executable, "-m", "sdit_path", "plan", str(cfg), "--out",
                                 str(out), "--force", "-q"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.5, 1.05) * duration)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        now = tree(out)
        assert now in (reference, reference2), f"kill {k}: a mixture or a loss"
        outcomes.add(now == reference)
    assert run("plan", str(SMALL), "--out", str(out), "--force", "-q").returncode == 0
    assert tree(out) == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.toml", "out", "ref2"]


def test_a_crash_between_the_fallback_renames_keeps_the_old_output(tmp_path):
    out = tmp_path / "out"
    write_tree(out, {"a.txt": "old"}, command="test")
    # the state the two-rename fallback leaves when killed between its renames
    os.rename(out, tmp_path / ".out.sdit-old-0123abcd")
    (tmp_path / ".out.sdit-new-89abcdef").mkdir()
    (tmp_path / ".out.sdit-new-89abcdef" / "a.txt").write_text("new, half")
    (tmp_path / ".out.user-notes").mkdir()  # not ours: never touched
    with pytest.raises(SditError, match="not empty"):
        write_tree(out, {"a.txt": "newer"}, command="test")
    assert (out / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.user-notes", "out"]
    write_tree(out, {"a.txt": "newer"}, force=True, command="test")
    assert tree(out) == {MARKER: (out / MARKER).read_bytes(), "a.txt": b"newer"}


@pytest.fixture
def full_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
                       capture_output=True)
    if r.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


@pytest.mark.slow
def test_a_full_disk_is_one_clear_line_from_every_writer(full_disk, small_plan, tmp_path):
    with pytest.raises(SditError, match="no space left on the device"):
        write_file(full_disk / "big.csv", "x" * 1_000_000)
    assert list(full_disk.iterdir()) == []
    with pytest.raises(SditError, match="no space left on the device"):
        write_tree(full_disk / "out", {"a.bin": b"x" * 1_000_000}, command="test")
    assert list(full_disk.iterdir()) == []
    trace = tmp_path / "t.csv"
    assert run("simulate", "--plan", str(small_plan), "--program", "GOLD_A", "--errors",
               "paper_table2", "--out", str(trace)).returncode == 0
    measured = tmp_path / "m.csv"
    assert run("perturb", "--plan", str(small_plan), "--program", "GOLD_A", "--seed", "2",
               "--out", str(measured)).returncode == 0
    for args in (["plan", str(SMALL), "--out", str(full_disk / "p")],
                 ["simulate", "--plan", str(small_plan), "--program", "GOLD_A", "--errors",
                  "paper_table2", "--out", str(full_disk / "s.csv")],
                 ["identify", "--plan", str(small_plan), "--trace", str(trace), "--json",
                  str(full_disk / "i.json")],
                 ["perturb", "--plan", str(small_plan), "--program", "GOLD_A", "--seed", "1",
                  "--out", str(full_disk / "m.csv")],
                 ["preview", str(SMALL), "--out", str(full_disk / "pv")],
                 ["diagnose", "--plan", str(small_plan), "--program", "GOLD_A", "--measured",
                  str(measured), "--json", str(full_disk / "d.json"), "--pictures",
                  str(full_disk / "pics")]):
        (full_disk / "filler").write_bytes(b"")
        with open(full_disk / "filler", "wb") as fh:  # leave almost nothing free
            try:
                fh.write(b"x" * 300_000)
            except OSError:
                pass
        r = run(*args)
        (full_disk / "filler").unlink()
        assert r.returncode == 5, (args[0], r.stderr)
        assert "no space left on the device" in one_error_line(r)
        assert list(full_disk.iterdir()) == [], args[0]


# --------------------------------------------------------------------------- fuzzing

def test_fuzz_config_loader():
    """Seeded mutations of the bundled samples: every one is either a valid config or a
    ConfigError with one line naming the file; nothing else escapes."""
    rng = random.Random(1414)
    bases = [BASE3, BASE5, sample_path("vmc_3axis_collision.toml").read_text()]
    cases = int(os.environ.get("SDIT_FUZZ_CASES", "400"))  # a longer campaign on request
    tried = accepted = 0
    for _ in range(cases):
        text = mutate_config(rng.choice(bases), rng)
        tried += 1
        try:
            parse_config(text, "fuzz.toml")
            accepted += 1
        except ConfigError as exc:
            msg = str(exc)
            assert msg.startswith("fuzz.toml") and "\n" not in msg and len(msg) < 500, msg[:600]
    assert tried == cases and 0 < accepted < tried
    print(f"config fuzz: {tried} tried, {accepted} accepted")


def test_fuzz_recording_reader(tmp_path):
    """Seeded mutations of a small recording: read or refused with one line naming the
    file; a reading it accepts has increasing finite times and no infinite values."""
    rng = random.Random(1415)
    base = _trace_text(n=400)
    p = tmp_path / "fuzz.csv"
    cases = int(os.environ.get("SDIT_FUZZ_CASES", "300"))
    tried = accepted = 0
    for _ in range(cases):
        p.write_text(mutate_trace(base, rng), encoding="utf-8")
        tried += 1
        try:
            tr = read_trace(p)
        except SditError as exc:
            msg = str(exc)
            assert msg.startswith(str(p)) and "\n" not in msg and len(msg) < 500, msg[:600]
            continue
        accepted += 1
        assert np.all(np.isfinite(tr.t_s)) and np.all(np.diff(tr.t_s) > 0)
        assert not np.any(np.isinf(tr.delta_l_um))
        assert int(np.isfinite(tr.delta_l_um).sum()) >= 100
    assert tried == cases and 0 < accepted < tried
    print(f"recording fuzz: {tried} tried, {accepted} accepted")
