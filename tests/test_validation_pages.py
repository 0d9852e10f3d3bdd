"""The validation page is generated from the campaigns' results files, never written by
hand: it must be what ``validation/tables.py`` prints."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_validation_page_is_generated_from_the_results():
    import tables  # validation/ is on the path (conftest)

    page = (ROOT / "docs" / "validation" / "index.md").read_text(encoding="utf-8")
    assert page == tables.page(), ("docs/validation/index.md is stale: run "
                                   "python validation/tables.py > docs/validation/index.md")


def test_every_hard_case_a_comment_names_is_in_the_validation_data():
    """A comment names the recording that motivated its rule by an id of
    ``validation/hard_cases.toml``; every id named is there, every case there is named."""
    import re
    import tomllib

    data = tomllib.loads((ROOT / "validation" / "hard_cases.toml").read_text(encoding="utf-8"))
    defined = [c["id"] for c in data["case"]]
    assert len(defined) == len(set(defined))
    pattern = re.compile(r"\b(blind-(?:bad|typical)-SDIT5?_[A-E]-s\d+-\d+|analyse-s\d+-\d+|"
                         r"test-[a-z0-9-]+[a-z0-9])")
    named = set()
    for folder in ("sdit_path", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            named |= set(pattern.findall(path.read_text(encoding="utf-8")))
    assert named <= set(defined), sorted(named - set(defined))
    assert set(defined) <= named, sorted(set(defined) - named)
