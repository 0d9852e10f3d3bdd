"""The hostile edits of a plan directory and of a recording, with what each must give:
kept here, beside the campaign that runs them end to end in their own processes
(``hostile_campaign.py``), and drawn from by ``tests/test_hostile.py``.

A plan edit is ``(edit(plan_dir), expected)``: the edit applied in place to a copy of a
plan of ``tests/data/golden_small.toml``, and a piece of the one line it must be refused
with (None: refused, by whatever reads it).  A recording case is ``(mutate(text),
exit_code, expected)``: the CSV text of a recording of GOLD_A edited, the exit code a
command reading it must end with and a piece of its one error line.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import re
from pathlib import Path

from sdit_path.plan.files import sealed


def _refingerprint(d: Path) -> None:
    """Make plan.json's fingerprints match the (edited) files: a deliberate, consistent
    edit, so that the content checks behind the fingerprints are exercised."""
    m = json.loads((d / "plan.json").read_text())
    for rel in m["files"]:
        if (d / rel).is_file():
            m["files"][rel] = hashlib.sha256((d / rel).read_bytes()).hexdigest()
    (d / "plan.json").write_text(json.dumps(sealed(m)))


def _traj_edit(fn, refingerprint=True):
    def apply(d: Path):
        p = d / "trajectories" / "GOLD_A.csv.gz"
        lines = gzip.decompress(p.read_bytes()).decode().splitlines()
        p.write_bytes(gzip.compress(("\n".join(fn(lines)) + "\n").encode()))
        if refingerprint:
            _refingerprint(d)
    return apply


def _manifest_edit(fn, reseal=True):
    """An edit of plan.json, sealed again (a deliberate, consistent edit that the value
    checks behind the seal must catch) or not (the seal must)."""
    def apply(d: Path):
        m = json.loads((d / "plan.json").read_text())
        m = fn(m)
        (d / "plan.json").write_text(json.dumps(sealed(m) if reseal else m))
    return apply


def _first_data(lines):
    return next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#")) + 1


PLAN_EDITS = {
    "plan.json not UTF-8": (lambda d: (d / "plan.json").write_bytes(b"\xff\xfe{}"), "not UTF-8"),
    "plan.json []": (lambda d: (d / "plan.json").write_text("[]"), "not a plan manifest"),
    "plan.json null": (lambda d: (d / "plan.json").write_text("null"), "not a plan manifest"),
    "plan.json a string": (lambda d: (d / "plan.json").write_text('"x"'), "not a plan manifest"),
    "plan.json a folder": (lambda d: ((d / "plan.json").unlink(), (d / "plan.json").mkdir()),
                           "is a directory"),
    "programs missing": (_manifest_edit(lambda m: {k: v for k, v in m.items() if k != "programs"}),
                         "programs: expected"),
    "trajectory a number": (_manifest_edit(lambda m: {**m, "programs": [
        {**p, "trajectory": 7} for p in m["programs"]]}), "programs: expected"),
    "tested_travel missing": (_manifest_edit(
        lambda m: {k: v for k, v in m.items() if k != "tested_travel"}), "tested_travel"),
    "trajectory outside": (_manifest_edit(lambda m: {**m, "programs": [
        {**p, "trajectory": "../../etc/passwd"} for p in m["programs"]]}), "outside the plan"),
    "trajectory absolute": (_manifest_edit(lambda m: {**m, "programs": [
        {**p, "trajectory": "/etc/passwd"} for p in m["programs"]]}), "outside the plan"),
    "plan.json edited": (_manifest_edit(lambda m: {**m, "machine": "another"}, reseal=False),
                         "changed since it was planned"),
    "plan.json unsealed": (_manifest_edit(lambda m: {k: v for k, v in m.items()
                                                     if k != "sealed_sha256"}, reseal=False),
                           "carries no seal"),
    "tested_travel zero width": (_manifest_edit(lambda m: {**m, "tested_travel": {
        **m["tested_travel"], "X": [5, 5]}}), "min < max"),
    "tested_travel unknown axis": (_manifest_edit(lambda m: {**m, "tested_travel": {
        **m["tested_travel"], "Q": [0, 5]}}), "not a linear axis"),
    "tested_travel NaN": (_manifest_edit(lambda m: {**m, "tested_travel": {
        **m["tested_travel"], "X": [float("nan"), 5]}}), "tested_travel"),
    "sphere radius NaN": (_manifest_edit(lambda m: {**m, "sphere": {
        **m["sphere"], "radius_mm": float("nan")}}), "finite"),
    "sphere moved": (_manifest_edit(lambda m: {**m, "sphere": {
        **m["sphere"], "radius_mm": m["sphere"]["radius_mm"] + 1}}), "differs from the config"),
    "config edited": (lambda d: (d / "config.toml").write_text(
        (d / "config.toml").read_text().replace("1000.0", "1200.0")), "changed since it was planned"),
    "trajectories swapped": (lambda d: (
        (d / "trajectories" / "GOLD_A.csv.gz").rename(d / "x"),
        (d / "trajectories" / "GOLD_B.csv.gz").rename(d / "trajectories" / "GOLD_A.csv.gz"),
        (d / "x").rename(d / "trajectories" / "GOLD_B.csv.gz")), "changed since it was planned"),
    "trajectory edited": (_traj_edit(lambda ls: ls[:-5], refingerprint=False),
                          "changed since it was planned"),
    "header only": (_traj_edit(lambda ls: ls[:_first_data(ls)]), "sample(s)"),
    "cut to 10 rows": (_traj_edit(lambda ls: ls[:_first_data(ls) + 10]), None),
    "a NaN": (_traj_edit(lambda ls: ls[:40] + [re.sub(r",[-0-9.]+,", ",nan,", ls[40], count=1)]
              + ls[41:]), "not a finite number"),
    "axis_X renamed": (_traj_edit(lambda ls: [ln.replace("axis_X_mm", "axis_Q_mm") for ln in ls]),
                       "axis columns"),
    "axis_X dropped": (_traj_edit(lambda ls: [
        ",".join(c for j, c in enumerate(ln.split(",")) if j != 4) if not ln.startswith("#")
        else ln for ln in ls]), "axis columns"),
    "time backwards": (_traj_edit(lambda ls: ls[:50] + [ls[52], ls[51], ls[50]] + ls[53:]),
                       "time does not increase"),
}


def _data_lines(text: str) -> tuple[list[str], list[str]]:
    lines = text.splitlines()
    return [ln for ln in lines if ln.startswith("#")], [ln for ln in lines
                                                         if not ln.startswith("#")]


def _part(text: str, share: float) -> str:
    head, body = _data_lines(text)
    return "\n".join(head + body[: max(2, int(len(body) * share))]) + "\n"


def _one_value(text: str, value: str) -> str:
    head, body = _data_lines(text)
    k = len(body) // 2
    t = body[k].split(",")[0]
    body[k] = f"{t},{value}"
    return "\n".join(head + body) + "\n"


#: recordings of GOLD_A that are not what they claim: (mutate, exit code, expected)
RECORDING_CASES = {
    "a reading of 1e308": (lambda t: _one_value(t, "1e308"), 2, "a ballbar reads within"),
    "a reading of -1e308": (lambda t: _one_value(t, "-1e308"), 2, "a ballbar reads within"),
    "one row": (lambda t: _part(t, 0.0), 6, "reading(s) that are numbers"),
    "every reading NaN": (lambda t: re.sub(r"(?m)^([-0-9.]+),[-0-9.e+]+$", r"\1,nan", t), 6,
                          "reading(s) that are numbers"),
    "a tenth of the program": (lambda t: _part(t, 0.1), 6, "GOLD_A"),
    "times in milliseconds": (lambda t: re.sub(
        r"(?m)^(\d+\.\d+),", lambda m: f"{float(m.group(1)) * 1000:.1f},", t), 2, "milliseconds"),
}
