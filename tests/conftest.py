from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sdit_path.config import load_config, parse_config, sample_path
from sdit_path.plan.pipeline import plan

DATA = Path(__file__).parent / "data"
GOLDEN = Path(__file__).parent / "golden"
#: the validation campaigns' own modules (the independent generator, the mutators)
VALIDATION = Path(__file__).resolve().parents[1] / "validation"
sys.path.insert(0, str(VALIDATION))


def pytest_addoption(parser):
    parser.addoption("--regen-golden", action="store_true",
                     help="rewrite tests/golden/ from the current code (review the diff!)")


@pytest.fixture(scope="session")
def regen_golden(request) -> bool:
    return request.config.getoption("--regen-golden")


@pytest.fixture(scope="session")
def default_config():
    return load_config()


@pytest.fixture(scope="session")
def default_plan(default_config):
    return plan(default_config)


@pytest.fixture(scope="session")
def default_text() -> str:
    return sample_path("vmc_3axis.toml").read_text()


@pytest.fixture(scope="session")
def plan_f1500(tmp_path_factory) -> Path:
    """The default sample planned at F1500 by the command line, once per session: the
    diagnosis tests and the self-check of ``perturb`` read it (and write nothing into
    it)."""
    import subprocess
    import sys

    d = tmp_path_factory.mktemp("f1500")
    cfg = d / "f1500.toml"
    cfg.write_text(sample_path("vmc_3axis.toml").read_text().replace(
        "feed_mm_per_min = 600.0", "feed_mm_per_min = 1500.0"))
    r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(cfg), "--out",
                        str(d / "plan"), "-q"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return d / "plan"


def edit(text: str, key: str, value: str, section: str | None = None) -> str:
    """Replace ``key = ...`` (in ``[section]`` when given) with ``key = value``."""
    if section is None:
        new, n = re.subn(rf"(?m)^{re.escape(key)}\s*=.*$", lambda _: f"{key} = {value}", text,
                         count=1)
    else:
        start = text.index(f"[{section}]\n")
        end = text.find("\n[", start + 1)
        end = len(text) if end < 0 else end
        block, n = re.subn(rf"(?m)^{re.escape(key)}\s*=.*$", lambda _: f"{key} = {value}",
                           text[start:end], count=1)
        new = text[:start] + block + text[end:]
    assert n == 1, f"{key} not found"
    return new


@pytest.fixture
def config_with(default_text):
    def make(key: str, value: str, section: str | None = None):
        return parse_config(edit(default_text, key, value, section), "test.toml")
    return make


@pytest.fixture(scope="session")
def five_axis_plan(tmp_path_factory) -> Path:
    """The bundled 5-axis sample, planned once per worker."""
    d = tmp_path_factory.mktemp("bc")
    r = subprocess.run([sys.executable, "-m", "sdit_path", "plan",
                        str(sample_path("bc_table_5axis.toml")), "--out", str(d / "P"), "-q"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return d / "P"


def have_linuxcnc() -> bool:
    return Path("/usr/lib/python3/dist-packages").glob("gcode*.so") is not None and any(
        Path("/usr/lib/python3/dist-packages").glob("gcode*.so")) and shutil.which("rs274") is not None


@pytest.fixture(scope="session")
def golden_plans(tmp_path_factory) -> dict:
    """``golden_small`` planned by the command at its feed (F1000, ``fast``) and at F400
    (``slow``): the recordings tests share them."""
    import subprocess
    import sys

    root = tmp_path_factory.mktemp("golden_plans")
    text = (DATA / "golden_small.toml").read_text()
    slow = root / "slow.toml"
    slow.write_text(text.replace("feed_mm_per_min = 1000.0", "feed_mm_per_min = 400.0"))
    out = {}
    for name, cfg in (("fast", DATA / "golden_small.toml"), ("slow", slow)):
        out[name] = root / name
        r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(cfg), "--out",
                            str(out[name]), "-q"], capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr
    return out
