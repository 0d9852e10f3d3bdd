"""Error sets: named values of model parameters, in a small TOML file.

    name = "..."
    [model]            # the model the values belong to (see ModelOptions)
    linear_order = 0
    rotary_order = 0
    squareness = false
    location = false
    [values]           # ISO names (um, urad); quote names with a dot: "EXX.P1" = 4.0
    EXX = 54.9
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError
from .model import ModelOptions


@dataclass(frozen=True, slots=True)
class ErrorSet:
    name: str
    options: ModelOptions
    values: tuple[tuple[str, float], ...]

    def as_dict(self) -> dict[str, float]:
        return dict(self.values)


def load_error_set(path: str | Path) -> ErrorSet:
    p = Path(path)
    if not p.is_file():
        from ..config import sample_path

        bundled = sample_path("vmc_3axis.toml").parent / "errors" / p.name
        if not p.suffix:
            bundled = bundled.with_suffix(".toml")
        if bundled.is_file():
            p = bundled
        else:
            raise ConfigError(str(path), "no such error-set file (bundled: paper_table2, "
                                         "five_axis_location)")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8-sig"))  # a byte-order mark is fine
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), f"cannot parse TOML: {exc}") from None
    for key in data:
        if key not in ("name", "model", "values"):
            raise ConfigError(str(p), f"{key}: unknown key; expected name, [model], [values]")
    m = data.get("model", {})
    known = ("linear_basis", "linear_order", "rotary_order", "squareness", "location")
    for key in m:
        if key not in known:
            raise ConfigError(str(p), f"model.{key}: unknown key; expected one of {', '.join(known)}")
    opts = ModelOptions(linear_basis=str(m.get("linear_basis", "legendre")),
                        linear_order=int(m.get("linear_order", 0)),
                        rotary_order=int(m.get("rotary_order", 0)),
                        squareness=bool(m.get("squareness", True)),
                        location=bool(m.get("location", True)))
    if opts.linear_basis not in ("legendre", "table"):
        raise ConfigError(str(p), f"model.linear_basis: expected legendre or table, got {opts.linear_basis!r}")
    values = data.get("values", {})
    out = []
    for k, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ConfigError(str(p), f"values.{k}: expected a finite number (um or urad), got {v!r}")
        out.append((k, float(v)))
    return ErrorSet(str(data.get("name", p.stem)), opts, tuple(out))
