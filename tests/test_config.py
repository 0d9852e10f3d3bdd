from __future__ import annotations

import pytest

from sdit_path.plan.configure import load_config, parse_config
from sdit_path.errors import ConfigError

from conftest import edit


def test_default_sample_loads(default_config):
    c = default_config
    assert c.ballbar.bar_length_mm == 150.0
    assert c.test.track_elevations_deg == (0.0, 18.0, 36.0, 54.0, 72.0)
    assert c.test.nodes_per_track == 6 and c.test.subsegments_per_sector == 3
    assert c.test.dwell_s == 2.0
    assert c.post.controllers == ("sinumerik840d", "linuxcnc")
    assert [a.name for a in c.machine.axes] == ["X", "Y", "Z"]


def test_values_are_frozen(default_config):
    with pytest.raises(AttributeError):
        default_config.ballbar.bar_length_mm = 1.0


BAD = [
    ("bar_length_mm", "0.0", None, "ballbar.bar_length_mm", "expected a value > 0"),
    ("bar_length_mm", "-5", None, "ballbar.bar_length_mm", "expected a value > 0"),
    ("bar_length_mm", "900.0", None, "ballbar.bar_length_mm", "instrument's reach"),
    ("pivot_mm", "[0.0, 900.0, 50.0]", None, "ballbar.pivot_mm", "outside the Y travel"),
    ("track_elevations_deg", "[0.0, 36.0, 18.0]", None, "test.track_elevations_deg",
     "strictly increasing"),
    ("track_elevations_deg", "[0.0, 45.0, 90.0]", None, "test.track_elevations_deg", "< 90"),
    ("controllers", '["sinumerik840d", "mazatrol"]', None, "post.controllers",
     "known controllers: fanuc, fanuc_nurbs, haas, heidenhain, linuxcnc, sinumerik840d"),
    ("feed_mm_per_min", "0.0", None, "test.feed_mm_per_min", "expected a value > 0"),
    ("feed_mm_per_min", '"fast"', None, "test.feed_mm_per_min", "expected a number in mm/min"),
    ("decimals", "2", None, "post.decimals", "expected a value >= 3"),
    ("projection", '"orthographic"', None, "test.projection", "stereographic, vertical"),
    ("travel_mm", "[400.0, -400.0]", "machine.axes.X", "machine.axes.X.travel_mm", "min < max"),
]


@pytest.mark.parametrize("key,value,section,where,expected", BAD)
def test_bad_values_name_key_line_and_expectation(default_text, key, value, section, where,
                                                  expected):
    text = edit(default_text, key, value, section)
    with pytest.raises(ConfigError) as err:
        parse_config(text, "bad.toml")
    msg = str(err.value)
    assert where in msg and expected in msg
    line = next(i for i, l in enumerate(text.splitlines(), 1) if l.startswith(f"{key} = {value}"))
    assert msg.startswith(f"bad.toml:{line}: ")


def test_unknown_key_is_caught_with_its_line(default_text):
    text = default_text.replace("feed_mm_per_min = 600.0", "feed_mm_per_s = 10.0")
    with pytest.raises(ConfigError) as err:
        parse_config(text, "bad.toml")
    line = next(i for i, l in enumerate(text.splitlines(), 1) if l.startswith("feed_mm_per_s"))
    assert f"bad.toml:{line}: test.feed_mm_per_s: unknown key" in str(err.value)
    assert "feed_mm_per_min" in str(err.value)


def test_unparseable_toml_names_file_and_line(default_text):
    text = default_text.replace("dwell_s = 2.0", "dwell_s = = 2.0")
    line = next(i for i, l in enumerate(text.splitlines(), 1) if l.startswith("dwell_s"))
    with pytest.raises(ConfigError) as err:
        parse_config(text, "broken.toml")
    assert str(err.value).startswith(f"broken.toml:{line}: cannot parse TOML")


def test_missing_section(default_text):
    text = default_text[: default_text.index("[ballbar]")]
    with pytest.raises(ConfigError, match="ballbar: missing table"):
        parse_config(text, "x.toml")


def test_missing_file_and_not_utf8(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "nope.toml")
    p = tmp_path / "latin1.toml"
    p.write_bytes(b"[machine]\nname = \"Fr\xe4se\"\n")
    with pytest.raises(ConfigError, match=r"latin1.toml:2: not UTF-8"):
        load_config(p)


def test_cap_elevation_must_lie_above_top_track(config_with):
    with pytest.raises(ConfigError, match="between the top track"):
        config_with("cap_elevation_deg", "60.0")


def test_feed_beyond_machine_is_refused(config_with):
    with pytest.raises(ConfigError, match="feed the machine can reach"):
        config_with("feed_mm_per_min", "90000.0")


def _with_overrides(text: str, *tables: str) -> str:
    return text + "".join(f"\n[[test.curve.override]]\n{t}\n" for t in tables)


def test_sector_overrides_parse_and_change_only_their_sector(default_text):
    cfg = parse_config(_with_overrides(default_text, 'sector = "D3"\namplitude = 0.5\nwaves_per_sector = 2',
                                       'sector = "B1"\nprojection = "vertical"'), "t.toml")
    curve = cfg.test.curve
    assert [o.sector for o in curve.overrides] == ["B1", "D3"]
    assert curve.for_sector("D", 3, "stereographic") == (0.5, 2, "stereographic")
    assert curve.for_sector("B", 1, "stereographic") == (1.0, 1, "vertical")
    assert curve.for_sector("D", 2, "stereographic") == (1.0, 1, "stereographic")


def test_a_sector_override_may_move_its_crest(default_text):
    cfg = parse_config(_with_overrides(default_text, 'sector = "D3"\ncrest_at = 0.35'), "t.toml")
    assert cfg.test.curve.crest_for("D", 3) == 0.35
    assert cfg.test.curve.crest_for("D", 2) == 0.5


def test_a_sector_override_may_set_its_own_feed(default_text):
    cfg = parse_config(_with_overrides(default_text, 'sector = "D3"\nfeed_mm_per_min = 300'),
                       "t.toml")
    assert cfg.test.curve.feed_for("D3-2", 600.0) == 300.0
    assert cfg.test.curve.feed_for("D2-2", 600.0) == 600.0
    assert cfg.test.sector_feeds("D") == (("D3", 300.0),)
    assert cfg.test.sector_feeds("C") == ()


@pytest.mark.parametrize("tables, message", [
    (['sector = "F1"'], r"override.sector: expected a layer letter \(A-E\) and a sector number 1-6"),
    (['sector = "D7"'], "sector number 1-6"),
    (['sector = "D03"'], "got 'D03'"),
    (['sector = 3'], "expected a string"),
    (['sector = "D3"\namplitude = 1.5'], r"override.amplitude: expected a value <= 1"),
    (['sector = "D3"\nwaves_per_sector = 0'], "override.waves_per_sector"),
    (['sector = "D3"\nprojection = "conic"'], "expected one of stereographic, vertical"),
    (['sector = "D3"\nfeed = 100'], r"override.feed: unknown key"),
    (['sector = "D3"\nfeed_mm_per_min = 0.5'], r"override.feed_mm_per_min: expected a feed of at least 1"),
    (['sector = "D3"\nfeed_mm_per_min = 1e6'], r"override.feed_mm_per_min: expected a feed the machine can reach"),
    (['sector = "D3"\nfeed_mm_per_min = "slow"'], r"override.feed_mm_per_min: expected a number"),
    (['sector = "D3"', 'sector = "D3"'], r"override\[2\].sector: expected each sector at most once"),
    (['sector = "D3"\ncrest_at = 0.2'], r"override.crest_at: expected a value >= 0.3"),
    (['sector = "D3"\ncrest_at = 0.8'], r"override.crest_at: expected a value <= 0.7"),
    (['sector = "D3"\ntilt_offset_deg = 5'], r"override.tilt_offset_deg: expected test.rotary.schedule"),
])
def test_bad_sector_overrides_name_the_field(default_text, tables, message):
    with pytest.raises(ConfigError, match=message):
        parse_config(_with_overrides(default_text, *tables), "t.toml")


def test_timing_control_chooses_whose_motion_the_plan_predicts(default_text):
    assert parse_config(default_text, "t.toml").timing.control == "jerk_limited"
    alone = edit(default_text, "controllers", '["linuxcnc"]')
    cfg = parse_config(alone + '\n[timing]\ncontrol = "linuxcnc"\n', "t.toml")
    assert cfg.timing.control == "linuxcnc"
    with pytest.raises(ConfigError, match=r"timing.control: .*post.controllers must be "
                                          r"\[\"linuxcnc\"\] alone"):
        parse_config(default_text + '\n[timing]\ncontrol = "linuxcnc"\n', "t.toml")
    with pytest.raises(ConfigError, match=r"timing.control.*jerk_limited, linuxcnc"):
        parse_config(alone + '\n[timing]\ncontrol = "fanuc"\n', "t.toml")
