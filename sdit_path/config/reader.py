"""Reading typed values from parsed TOML: every problem becomes a
:class:`~sdit_path.errors.ConfigError` naming the file, the line (when it can be found)
and the dotted key, what was expected and what arrived."""

from __future__ import annotations

import math
import re
from typing import Any

from ..errors import ConfigError


def line_of(text: str, dotted: str) -> int | None:
    """Best-effort line number (1-based) of a dotted key in TOML text."""
    m = re.fullmatch(r"(.+)\[(\d+)\](?:\.(.+))?", dotted)
    if m:  # an array of tables: the k-th [[table]] header, then the key below it
        array, k, item = m.group(1), int(m.group(2)), m.group(3)
        lines = text.splitlines()
        starts = [i for i, raw in enumerate(lines)
                  if re.match(rf"^\s*\[\[\s*{re.escape(array)}\s*\]\]", raw)]
        if k >= len(starts):
            return None
        end = next((i for i in range(starts[k] + 1, len(lines))
                    if re.match(r"^\s*\[", lines[i])), len(lines))
        for i in range(starts[k] + 1, end):
            if item and re.match(rf"^\s*{re.escape(item)}\s*=", lines[i]):
                return i + 1
        return starts[k] + 1
    parts = dotted.split(".")
    table: list[str] = []
    header = re.compile(r"^\s*\[\s*([^\]]+?)\s*\]\s*(#.*)?$")
    for number, raw in enumerate(text.splitlines(), start=1):
        m = header.match(raw)
        if m:
            table = [p.strip().strip('"') for p in m.group(1).split(".")]
            continue
        m = re.match(r"^\s*([A-Za-z0-9_\-\.\"]+)\s*=", raw)
        if not m:
            continue
        key = [p.strip().strip('"') for p in m.group(1).split(".")]
        if table + key == parts:
            return number
    # a table itself, e.g. a missing key inside it: point at its header
    for number, raw in enumerate(text.splitlines(), start=1):
        m = header.match(raw)
        if m and [p.strip().strip('"') for p in m.group(1).split(".")] == parts[:-1]:
            return number
    return None


class Reader:
    """Reads typed values from a nested dict, naming file, line and key on errors."""

    def __init__(self, source: str, text: str):
        self.source = source
        self.text = text

    def fail(self, key: str, message: str) -> ConfigError:
        line = line_of(self.text, key) if key and len(key) < 200 else None
        where = f"{self.source}:{line}" if line else self.source
        shown = key if len(key) <= 80 else key[:77] + "..."
        return ConfigError(where, f"{shown}: {message}" if key else message)

    def table(self, data: dict, key: str, known: tuple[str, ...], required: bool = True) -> dict:
        value = data.get(key.rsplit(".", 1)[-1])
        if value is None:
            if required:
                raise self.fail(key, "missing table; expected a [" + key + "] section")
            value = {}
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {describe(value)}")
        self.no_unknown(value, key, known)
        return value

    def no_unknown(self, data: dict, prefix: str, known: tuple[str, ...]) -> None:
        for k in data:
            if k not in known:
                dotted = f"{prefix}.{k}" if prefix else k
                raise self.fail(dotted, f"unknown key; expected one of: {', '.join(known)}")

    def number(self, data: dict, key: str, default: float | None = None, *,
               gt: float | None = None, ge: float | None = None,
               lt: float | None = None, le: float | None = None, unit: str = "") -> float:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, f"missing; expected a number{unit_text(unit)}")
            return float(default)
        value = data[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"expected a number{unit_text(unit)}, got {describe(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(key, f"expected a finite number{unit_text(unit)}, got {value}")
        check_bounds(self, key, value, gt, ge, lt, le, unit)
        return value

    def integer(self, data: dict, key: str, default: int | None = None, *,
                ge: int | None = None, le: int | None = None) -> int:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, "missing; expected an integer")
            return default
        value = data[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"expected an integer, got {describe(value)}")
        check_bounds(self, key, float(value), None, ge, None, le, "")
        return value

    def string(self, data: dict, key: str, default: str | None = None,
               choices: tuple[str, ...] | None = None) -> str:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, "missing; expected a string")
            return default
        value = data[name]
        if not isinstance(value, str):
            raise self.fail(key, f"expected a string, got {describe(value)}")
        if choices is not None and value not in choices:
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {short(value)}")
        if len(value) > 1000:
            raise self.fail(key, f"expected at most 1000 characters, got {len(value)}")
        return value

    def vector(self, data: dict, key: str, length: int, default: tuple | None = None,
               unit: str = "", bound: float = 1e4) -> tuple[float, ...]:
        """``length`` finite numbers, each within +-``bound`` (a physical plausibility
        limit, 10 m by default: nothing on a machine tool lies further away)."""
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, f"missing; expected {length} numbers{unit_text(unit)}")
            return tuple(float(v) for v in default)
        value = data[name]
        if (not isinstance(value, list) or len(value) != length
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.fail(key, f"expected a list of {length} numbers{unit_text(unit)}, "
                                 f"got {describe(value)}")
        out = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in out):
            raise self.fail(key, f"expected finite numbers, got {list(out)}")
        if any(abs(v) > bound for v in out):
            raise self.fail(key, f"expected values within +-{bound:g}{unit_text(unit)} (a plausible "
                                 f"machine), got {[float(f'{v:.6g}') for v in out]}")
        return out

    def xyz(self, data: dict, key: str, default: tuple | None = None, unit: str = "",
            bound: float = 1e4) -> tuple[float, float, float]:
        """:meth:`vector` of a point or a direction."""
        x, y, z = self.vector(data, key, 3, default, unit, bound)
        return (x, y, z)

    def span(self, data: dict, key: str, default: tuple | None = None, unit: str = "",
             bound: float = 1e4) -> tuple[float, float]:
        """:meth:`vector` of a range ``[min, max]`` (not checked for order here)."""
        lo, hi = self.vector(data, key, 2, default, unit, bound)
        return (lo, hi)

    def numbers(self, data: dict, key: str, default: tuple, unit: str = "") -> tuple[float, ...]:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return tuple(float(v) for v in default)
        value = data[name]
        if (not isinstance(value, list) or not value
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.fail(key, f"expected a non-empty list of numbers{unit_text(unit)}, "
                                 f"got {describe(value)}")
        out = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in out):
            raise self.fail(key, f"expected finite numbers, got {list(out)}")
        return out

    def boolean(self, data: dict, key: str, default: bool) -> bool:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return default
        value = data[name]
        if not isinstance(value, bool):
            raise self.fail(key, f"expected true or false, got {describe(value)}")
        return value

    def strings(self, data: dict, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return default
        value = data[name]
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise self.fail(key, f"expected a non-empty list of strings, got {describe(value)}")
        return tuple(value)


def unit_text(unit: str) -> str:
    return f" in {unit}" if unit else ""


def short(text: str, limit: int = 60) -> str:
    """repr of a user's string, cut so that an error line stays one readable line."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text)} chars)"


def describe(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"string {short(value)}"
    return f"{type(value).__name__} {short(repr(value))}"


def check_bounds(reader: Reader, key: str, value: float, gt, ge, lt, le, unit: str) -> None:
    u = f" {unit}" if unit else ""
    if gt is not None and not value > gt:
        raise reader.fail(key, f"expected a value > {gt:g}{u}, got {value:g}")
    if ge is not None and not value >= ge:
        raise reader.fail(key, f"expected a value >= {ge:g}{u}, got {value:g}")
    if lt is not None and not value < lt:
        raise reader.fail(key, f"expected a value < {lt:g}{u}, got {value:g}")
    if le is not None and not value <= le:
        raise reader.fail(key, f"expected a value <= {le:g}{u}, got {value:g}")

