from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sdit_path.config import load_config, parse_config, sample_path
from sdit_path.plan.pipeline import plan

DATA = Path(__file__).parent / "data"
GOLDEN = Path(__file__).parent / "golden"
#: the validation campaigns' own modules (the independent generator, the mutators)
VALIDATION = Path(__file__).resolve().parents[1] / "validation"
sys.path.insert(0, str(VALIDATION))


def pytest_collection_modifyitems(config, items):
    """The modules holding a campaign (minutes each) first, each module kept whole (its
    module-scoped fixtures are made once): two workers then share the long tests from
    the start instead of one of them finishing a long one alone at the end."""
    heavy = {item.module for item in items if item.get_closest_marker("campaign")}
    items.sort(key=lambda item: item.module not in heavy)  # stable


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


def run(*args, timeout=1200):
    return subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                          text=True, timeout=timeout)


def geometry_file(path, seed):
    """Random geometry of a few um and tens of urad (linear order 1 + squareness)."""
    from analyse_blind import geometry  # validation/ is on the path (above)

    values = geometry(np.random.default_rng(seed))
    body = "\n".join(f'"{k}" = {v:.4f}' for k, v in values.items())
    path.write_text(f'name = "hidden {seed}"\n\n[model]\nlinear_order = 1\nsquareness = true\n'
                    f"\n[values]\n{body}\n")
    return values


@pytest.fixture(scope="session")
def perturbed(tmp_path_factory, golden_plans):
    """Two recordings of the fast golden plan by ``perturb``: hidden geometry, a 2 ms
    servo mismatch of Y, unknown starts and clocks (the tests that only need recordings
    of the plan take these; ``recorded`` analyses them)."""
    root = tmp_path_factory.mktemp("analyse")
    plan = golden_plans["fast"]
    truth = geometry_file(root / "hidden.toml", seed=7)
    files = []
    for k, (prog, lead, ppm) in enumerate((("GOLD_A", 6.0, 90.0), ("GOLD_B", 11.0, -140.0))):
        rec = root / f"rec{k}.csv"
        r = run("perturb", "--plan", str(plan), "--program", prog, "--model",
                str(root / "hidden.toml"), "--effect", "servo_mismatch:axis=Y,extra_lag_ms=2.0",
                "--lead-s", str(lead), "--clock-ppm", str(ppm), "--noise-um", "0.2",
                "--out", str(rec), "--truth", str(root / f"truth{k}.json"), "-q")
        assert r.returncode == 0, r.stderr
        files.append(rec)
    return {"root": root, "plan": plan, "files": files, "truth": truth}


@pytest.fixture(scope="session")
def recorded(perturbed):
    """``perturbed`` analysed by the command line (its report.html included)."""
    out = perturbed["root"] / "out"
    r = run("analyse", "--plan", str(perturbed["plan"]), "--measured", str(perturbed["files"][1]),
            "--measured", str(perturbed["files"][0]), "--out", str(out), "--no-pictures")
    return {**perturbed, "out": out, "run": r}
