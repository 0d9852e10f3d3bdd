"""The words and units a metrologist reads: an effect's parameters as labelled values in
their usual unit, with what a value without an uncertainty is; the effects of one kind
found in several recordings brought to one figure; the set-up kept apart from the
findings.  Every name and note comes from the effect registry's traits."""

from __future__ import annotations

import math

from ..diagnose.effects import EFFECTS
from ..errormodel.model import ModelOptions

_BY_NAME = {e.name: e for e in EFFECTS}

#: the effects the report's first page lists even where no recording shows them
HEADLINE = tuple(e.name for e in sorted((e for e in EFFECTS if e.headline is not None),
                                        key=lambda e: e.headline))

#: parameter-name suffix -> unit, longest first
_UNITS = (("_um_per_m", "um/m"), ("_mm_s", "mm/s"), ("_per_s", "1/s"), ("_urad", "urad"),
          ("_ms", "ms"), ("_um", "um"), ("_hz", "Hz"), ("_deg", "deg"), ("_mm", "mm"),
          ("_s", "s"))


def effect_name(effect: str) -> str:
    """An effect's name as the trade says it."""
    cls = _BY_NAME.get(effect)
    return (cls.trade_name if cls is not None and cls.trade_name else
            effect.replace("_", " "))


def is_setup(effect: str) -> bool:
    """Is the effect part of the mounting (reported once, as the set-up)?"""
    cls = _BY_NAME.get(effect)
    return bool(cls is not None and cls.mounting)


def in_geometry(effect: str, options: dict) -> bool:
    """Does the identification's model (its options as the JSON gives them) hold what
    the effect reads, so that the geometry's figures report it?"""
    cls = _BY_NAME.get(effect)
    try:
        return bool(cls is not None and cls.covered_by(ModelOptions(**options)))
    except TypeError:
        return False


def _note(effect: str | None, key: str) -> str:
    cls = _BY_NAME.get(effect or "")
    return cls.parameter_notes.get(key, "") if cls is not None else ""


def split_unit(key: str) -> tuple[str, str]:
    """``lag_Y_minus_X_ms`` -> (``lag Y - X``, ``ms``)."""
    for suffix, unit in _UNITS:
        if key.endswith(suffix):
            label = key[: -len(suffix)]
            break
    else:
        label, unit = key, ""
    return label.replace("_minus_", " - ").replace("_", " "), unit


def parameter_rows(params: dict, std: dict, effect: str | None = None) -> list[dict]:
    """One row per parameter: ``label``, ``value``, ``std`` (k=1; None when the value was
    read off a search grid, which has no uncertainty), ``unit``, ``note``."""
    rows = []
    for key, value in params.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        label, unit = split_unit(key)
        s = std.get(key)
        note = _note(effect, key)
        if s is None:
            note = ("read off the search grid, no uncertainty" + (f"; {note}" if note else ""))
        rows.append({"key": key, "label": label, "value": float(value),
                     "std": None if s is None else float(s), "unit": unit, "note": note})
    return rows


def row_text(row: dict, k: int = 2) -> str:
    """``label value +- U unit`` with the expanded uncertainty (``k``) or the note."""
    if row["std"] is None:
        return f"{row['label']} {_g(row['value'])} {row['unit']} ({row['note']})"
    return (f"{row['label']} {_g(row['value'])} +- {_g(k * row['std'])} {row['unit']}"
            + (f" ({row['note']})" if row["note"] else ""))


def _g(v: float) -> str:
    return f"{v:.4g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.2e}"


def pooled(hits: list[dict], effect: str | None = None) -> list[dict]:
    """An effect found in several recordings, each parameter brought to one figure: the
    inverse-variance mean with its standard uncertainty raised by the Birge ratio where
    the recordings scatter more than their own uncertainties say; for values read off a
    grid, the range.  Each row: ``label``, ``unit``, ``value``, ``std`` (k=1, or None),
    ``low``, ``high``, ``n`` (recordings), ``birge``."""
    keys: dict[str, None] = {}
    for h in hits:
        for key in h["parameters"]:
            keys.setdefault(key, None)
    out = []
    for key in keys:
        vals = [(float(h["parameters"][key]), h.get("parameter_std", {}).get(key))
                for h in hits if isinstance(h["parameters"].get(key), (int, float))]
        if not vals:
            continue
        label, unit = split_unit(key)
        xs = [v for v, _ in vals]
        row = {"key": key, "label": label, "unit": unit, "n": len(vals), "low": min(xs),
               "high": max(xs), "value": None, "std": None, "birge": None,
               "note": _note(effect, key)}
        if all(s is not None and s > 0 for _, s in vals):
            w = [1.0 / float(s) ** 2 for _, s in vals]
            mean = sum(wi * x for wi, x in zip(w, xs)) / sum(w)
            std = 1.0 / math.sqrt(sum(w))
            birge = 1.0
            if len(vals) > 1:
                chi2 = sum(wi * (x - mean) ** 2 for wi, x in zip(w, xs))
                birge = max(1.0, math.sqrt(chi2 / (len(vals) - 1)))
            row.update(value=mean, std=std * birge, birge=birge)
        out.append(row)
    return out
