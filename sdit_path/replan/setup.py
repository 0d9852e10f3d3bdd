"""Set-up changes for a layer whose reasons no curve of its patch can change (an
infeasible segment, a clearance at a node): a higher track, a tilted equator, a higher
pivot, a longer tool, each planned like any layer.
"""

from __future__ import annotations

import math
import re

from ..config import Config
from ..errors import ConfigError
from ..interference.scene import Scene
from ..machine.kinematics import Kinematics
from ..plan.configure import parse_config
from .evaluate import evaluate_layer




#: set-up changes tried for a layer whose infeasible segments no curve in their patch
#: makes feasible (each planned: the layer's lower track raised, the pivot raised, a
#: longer tool)
TRACK_RAISE_DEG = (2.0, 5.0, 10.0)


#: with moving rotary axes, changes of the schedule's tilt at the equator (deg)
EQUATOR_TILT_DEG = (-10.0, 10.0)


PIVOT_RAISE_MM = (20.0, 50.0)


TOOL_LONGER_MM = (20.0, 50.0)


def _edit(text: str, section: str, key: str, value: str) -> str | None:
    """``text`` with ``key = value`` in ``[section]`` (None if the key is not there)."""
    m = re.search(r"(?m)^\[" + re.escape(section) + r"\]\s*$", text)
    if m is None:
        return None
    nxt = re.search(r"(?m)^\s*\[", text[m.end():])
    end = m.end() + (nxt.start() if nxt else len(text) - m.end())
    block, n = re.subn(r"(?m)^" + re.escape(key) + r"\s*=.*$", f"{key} = {value}",
                       text[m.end():end], count=1)
    return text[:m.end()] + block + text[end:] if n else None


def setup_changes(cfg: Config, layer: str, segments: list[str], travel: dict,
                  on_step=None, clearance: float | None = None) -> list[dict]:
    """Which set-up change makes ``segments`` of ``layer`` feasible (with ``clearance``,
    mm: also clear by that much), each found by planning the layer with it: its lower
    track raised, the pivot raised, a longer tool, and with moving rotary axes the tilt
    at the equator changed."""
    t = cfg.test
    names = "ABCDEFGHIJKLMNOPQRSTUVWXY"
    i = names.index(layer)
    elev = list(t.track_elevations_deg)
    trials = []
    for d in TRACK_RAISE_DEG:
        e = elev[:i] + [elev[i] + d] + elev[i + 1:]
        if all(b > a for a, b in zip(e, e[1:])) and e[-1] < 90:
            trials.append((f"track {layer} at {e[i]:g} deg instead of {elev[i]:g}",
                           "test", "track_elevations_deg", "[" + ", ".join(f"{x:g}" for x in e) + "]"))
    px, py, pz = cfg.ballbar.pivot_mm
    for d in PIVOT_RAISE_MM:
        trials.append((f"pivot {d:g} mm higher (Z {pz + d:g})", "ballbar", "pivot_mm",
                       f"[{px!r}, {py!r}, {pz + d!r}]"))
    for d in TOOL_LONGER_MM:
        trials.append((f"tool {d:g} mm longer ({cfg.machine.tool_length_mm + d:g} mm)", "machine",
                       "tool_length_mm", repr(cfg.machine.tool_length_mm + d)))
    if t.rotary.schedule == "moving":
        now = math.degrees(t.rotary.tilt_at_equator_rad)
        for d in EQUATOR_TILT_DEG:
            trials.append((f"tilt at the equator {now + d:g} deg instead of {now:g}", "test.rotary",
                           "tilt_at_equator_deg", f"{now + d:g}"))
    out = []
    for label, section, key, value in trials:
        text = _edit(cfg.text, section, key, value)
        if text is None:
            out.append({"change": label, "planned": False, "why": f"{section}.{key} is not in the config"})
            continue
        if on_step:
            on_step(f"trying a set-up change for layer {layer}: {label}")
        try:
            c2 = parse_config(text, cfg.source)
            kin = Kinematics(c2.machine)
            ev = evaluate_layer(c2, layer, travel, kin, Scene(c2, kin))
        except (ConfigError, ValueError) as exc:
            out.append({"change": label, "planned": False, "why": str(exc)[:200]})
            continue
        still = [sid for sid in segments if not ev.values.get(sid, {}).get("feasible", False)]
        clear = [ev.values[sid]["clearance_mm"] for sid in segments
                 if ev.values.get(sid, {}).get("clearance_mm") is not None]
        low = min(clear) if clear else None
        out.append({"change": label, "planned": True, "config": f"[{section}] {key} = {value}",
                    "feasible": not still and (clearance is None
                                               or (low is not None and low >= clearance)),
                    "still_infeasible": still, "layer_feasible": ev.feasible,
                    "min_clearance_mm": low,
                    **({"clearance_needed_mm": clearance} if clearance is not None else {})})
    return out
