"""The installed wheel, not the checkout: build it, install it into a fresh virtual
environment and plan the bundled sample from a directory far from the source tree."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def sh(*cmd, cwd=None) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, cwd=cwd, timeout=900)
    assert r.returncode == 0, f"{cmd}:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    return r


@pytest.mark.slow
def test_installed_wheel_finds_posts_templates_and_samples(tmp_path):
    dist = tmp_path / "dist"
    sh(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", dist, ROOT)
    wheel = next(dist.glob("sdit_path-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for needed in ("sdit_path/postprocessors/sinumerik840d.py", "sdit_path/postprocessors/linuxcnc.py",
                   "sdit_path/templates/sinumerik840d/program.mpf.j2",
                   "sdit_path/templates/linuxcnc/program.ngc.j2", "sdit_path/samples/vmc_3axis.toml"):
        assert needed in names, f"{needed} missing from {wheel.name}"
    # a fresh venv; the heavy dependencies come from the running environment's
    # site-packages (appended after the venv's own, so no network is needed), but
    # sdit_path itself only from the wheel
    venv = tmp_path / "venv"
    sh(sys.executable, "-m", "venv", venv)
    py = venv / "bin" / "python"
    own = sh(py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").stdout.strip()
    outer = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(own) / "outer-env.pth").write_text("\n".join(sorted(outer)) + "\n")
    sh(py, "-m", "pip", "install", "--no-deps", "--no-index", "--force-reinstall", wheel)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = sh(py, "-c", "import sdit_path; print(sdit_path.__file__)", cwd=elsewhere).stdout.strip()
    assert where.startswith(str(venv)), where
    out = elsewhere / "out"
    sh(venv / "bin" / "sdit-path", "plan", "--out", out, "-q", cwd=elsewhere)
    m = json.loads((out / "plan.json").read_text())
    assert {p["file"] for p in m["programs"]} >= {"sinumerik840d/SDIT_A.MPF", "linuxcnc/SDIT_E.ngc"}
