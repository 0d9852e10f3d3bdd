"""Reading ballbar traces: the contract with users' instruments.

UTF-8 CSV.  Optional leading ``# key: value`` lines.  A header row with at least
``t_s`` and ``delta_l_um`` (or ``delta_l_mm``), in any column order; other columns are
kept when they are ``segment``/``phase`` and ignored otherwise.  Empty or NaN values
are dropouts.  Anything else - no such columns, a non-numeric value, time going
backwards, no data - is an error naming the file and line.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import SditError
from .simulate import Trace


class TraceError(SditError):
    """A trace file that cannot be read; the message names the file and line."""

    exit_code = 2


def read_trace(path: str | Path) -> Trace:
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise TraceError(f"{p}: no such trace file") from None
    except IsADirectoryError:
        raise TraceError(f"{p}: is a directory, expected a trace CSV") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise TraceError(f"{p}:{line}: not UTF-8 text") from None
    header: dict[str, str] = {}
    lines = text.splitlines()
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        line = lines[k].lstrip("#").strip()
        if ":" in line:
            key, value = line.split(":", 1)
            header[key.strip()] = value.strip()
        k += 1
    if k >= len(lines):
        raise TraceError(f"{p}: no header row; expected columns t_s and delta_l_um (or delta_l_mm)")
    cols = [c.strip() for c in lines[k].split(",")]
    if "t_s" not in cols or not ({"delta_l_um", "delta_l_mm"} & set(cols)):
        raise TraceError(f"{p}:{k + 1}: header row {lines[k][:80]!r} lacks t_s and delta_l_um "
                         f"(or delta_l_mm)")
    fast = _read_fast(p, text, lines, k, cols, header)
    if fast is not None:
        return fast
    it = cols.index("t_s")
    unit = "delta_l_um" if "delta_l_um" in cols else "delta_l_mm"
    il = cols.index(unit)
    factor = 1.0 if unit == "delta_l_um" else 1000.0
    iseg = cols.index("segment") if "segment" in cols else None
    iph = cols.index("phase") if "phase" in cols else None
    body = lines[k + 1:]
    t = np.empty(len(body))
    dl = np.empty(len(body))
    seg = np.empty(len(body), dtype=object)
    ph = np.empty(len(body), dtype=object)
    n = 0
    for j, line in enumerate(body, start=k + 2):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split(",")
        if len(parts) < len(cols):
            raise TraceError(f"{p}:{j}: {len(parts)} fields, expected {len(cols)} (truncated line?)")
        try:
            tv = float(parts[it])
        except ValueError:
            raise TraceError(f"{p}:{j}: t_s {parts[it]!r} is not a number") from None
        if not math.isfinite(tv):
            raise TraceError(f"{p}:{j}: t_s is not finite")
        if n and tv <= t[n - 1]:
            raise TraceError(f"{p}:{j}: time goes backwards or repeats ({tv} s after {t[n - 1]} s)")
        cell = parts[il].strip()
        if cell == "" or cell.lower() == "nan":
            lv = np.nan
        else:
            try:
                lv = float(cell) * factor
            except ValueError:
                raise TraceError(f"{p}:{j}: {unit} {cell!r} is not a number") from None
            if math.isinf(lv):
                raise TraceError(f"{p}:{j}: {unit} {cell!r} is not finite (a dropout is empty or nan)")
        t[n], dl[n] = tv, lv
        seg[n] = parts[iseg].strip() if iseg is not None else ""
        ph[n] = parts[iph].strip() if iph is not None else ""
        n += 1
    if n == 0:
        raise TraceError(f"{p}: no data rows after the header")
    return Trace(t[:n], dl[:n], seg[:n], ph[:n], header)


def _read_fast(p: Path, text: str, lines: list[str], k: int, cols: list[str],
               header: dict) -> Trace | None:
    """The common case through pandas' C parser; None when anything is off, so the
    line-by-line reader finds and names the offending line."""
    import io

    import pandas as pd

    if len(set(cols)) != len(cols):
        return None
    unit = "delta_l_um" if "delta_l_um" in cols else "delta_l_mm"
    body = "\n".join(lines[k + 1:])
    if not body.strip() or "#" in body:
        return None
    if body.count(",") != (len(cols) - 1) * (len(lines) - k - 1):
        return None  # a short or long line somewhere: let the careful reader name it
    try:
        df = pd.read_csv(io.StringIO(body), header=None, names=cols, usecols=["t_s", unit],
                         dtype=float, engine="c", skip_blank_lines=False,
                         na_values=["", "nan", "NaN"], keep_default_na=False)
    except (ValueError, pd.errors.ParserError):
        return None
    t = df["t_s"].to_numpy(dtype=float)
    dl = df[unit].to_numpy(dtype=float) * (1.0 if unit == "delta_l_um" else 1000.0)
    if len(t) != len(lines) - k - 1 or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        return None
    if np.isinf(dl).any():
        return None
    n = len(t)
    empty = np.full(n, "", dtype=object)
    seg, ph = empty, empty
    if "segment" in cols or "phase" in cols:
        return None  # keep the labels: the careful reader does that
    return Trace(t, dl, seg, ph, header)
