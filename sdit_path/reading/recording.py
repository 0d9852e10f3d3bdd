"""Reading ballbar traces: the contract with users' instruments.

UTF-8 CSV.  Optional leading ``# key: value`` lines.  A header row with at least
``t_s`` and ``delta_l_um`` (or ``delta_l_mm``), in any column order; other columns are
kept when they are ``segment``/``phase`` and ignored otherwise.  Empty or NaN values
are dropouts.  What a spreadsheet export writes is read too, where it is unambiguous:
columns separated by ``;`` or tabs (then a decimal comma is read as a point), quoted
header names and cells.  Anything else - no such columns, a non-numeric value, time
going backwards, no data, times that are not seconds from the start of the recording
(milliseconds, epoch timestamps) - is an error naming the file and line.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import RecordingError, SditError
from .trace import Trace


class TraceError(SditError):
    """A trace file that cannot be read; the message names the file and line."""

    exit_code = 2


#: No ballbar reads further than this from its length (um): a reading beyond is not a
#: reading (a sensor's range is about +-1 mm; 10 mm leaves room for any instrument)
MAX_READING_UM = 10_000.0

#: A recording with fewer readings than this holds no usable information.
MIN_SAMPLES = 100
#: Slowest plausible sample rate of a ballbar recording (Hz).
MIN_RATE_HZ = 10.0


def _cell(text: str, limit: int = 40) -> str:
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text)} chars)"


def _dialect(p: Path, header_line: str, first_row: str | None, lineno: int) -> tuple[str, bool]:
    """(column separator, decimal comma) of a trace file, or a TraceError saying what
    to change when the format is ambiguous."""
    if "\t" in header_line:
        sep = "\t"
    elif ";" in header_line:
        sep = ";"
    else:
        sep = ","
    decimal_comma = sep != "," and first_row is not None and "," in first_row
    if sep == "," and first_row is not None:
        n_head = header_line.count(",") + 1
        n_row = first_row.count(",") + 1
        if n_row > n_head and ";" not in first_row:
            raise TraceError(f"{p}:{lineno + 1}: {n_row} fields under a header of {n_head}; if "
                             f"the numbers use decimal commas, separate the columns with ';' or "
                             f"tabs (or write decimal points)")
    return sep, decimal_comma


def _canonical(text: str, sep: str, decimal_comma: bool) -> str:
    """The same table as plain comma-separated text with decimal points."""
    if '"' in text:
        text = text.replace('"', "")
    if sep != ",":
        if decimal_comma:
            text = text.replace(",", ".")
        text = text.replace(sep, ",")
    return text


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
        lineno = raw[: exc.start].count(b"\n") + 1
        raise TraceError(f"{p}:{lineno}: not UTF-8 text") from None
    header: dict[str, str] = {}
    # (a recording of an hour holds millions of lines: split whole only where a line
    # is to be named; the common case is read from the text)
    text = text.replace("\r\n", "\n")
    lines, whole = _leading_lines(text)
    k0 = 0
    while k0 < len(lines) and (lines[k0].startswith("#") or not lines[k0].strip()):
        k0 += 1
    if k0 + 50 >= len(lines) and not whole:  # the header further down than that
        lines, whole = text.splitlines(), True
    if k0 < len(lines):
        first = next((ln for ln in lines[k0 + 1:k0 + 50] if ln.strip() and not ln.startswith("#")),
                     None)
        sep, decimal_comma = _dialect(p, lines[k0], first, k0 + 1)
        if sep != "," or '"' in text:
            lines = text.splitlines()
            head, body = "\n".join(lines[:k0]), "\n".join(lines[k0:])
            text = head + ("\n" if head else "") + _canonical(body, sep, decimal_comma)
            lines, whole = text.splitlines(), True
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        line = lines[k].lstrip("#").strip()
        if ":" in line:
            key, value = line.split(":", 1)
            header[key.strip()] = value.strip()
        k += 1
    return _read_rows(p, text, lines, header, k, whole)


#: the line breaks :meth:`str.splitlines` knows besides "\n"
_OTHER_BREAKS = "\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"


def _leading_lines(text: str, count: int = 200) -> tuple[list[str], bool]:
    """The first ``count`` lines of ``text`` as ``text.splitlines()`` gives them, and
    whether that is all of them (the whole text is split where it holds a line break
    other than "\n")."""
    if any(ch in text for ch in _OTHER_BREAKS):
        return text.splitlines(), True
    head = text.split("\n", count)
    if len(head) <= count:  # all of it
        return text.splitlines(), True
    return head[:count], False


def _read_rows(p: Path, text: str, lines: list[str], header: dict, k: int,
               whole: bool) -> Trace:
    """The rows after the header row ``lines[k]``; ``lines``: the text's first lines, or
    all of them (``whole``)."""
    if k >= len(lines):
        raise TraceError(f"{p}: no header row; expected columns t_s and delta_l_um (or delta_l_mm)")
    cols = [c.strip() for c in lines[k].split(",")]
    if "t_s" not in cols or not ({"delta_l_um", "delta_l_mm"} & set(cols)):
        raise TraceError(f"{p}:{k + 1}: header row {_cell(lines[k], 80)} lacks t_s and "
                         f"delta_l_um (or delta_l_mm)")
    # the rows' text: after the header row's line break
    at = sum(len(ln) + 1 for ln in lines[:k + 1]) if not whole else None
    body = text[at:] if at is not None else "\n".join(lines[k + 1:])
    rows = (body.count("\n") + (1 if body and not body.endswith("\n") else 0)) if not whole \
        else len(lines) - k - 1
    fast = _read_fast(p, body, rows, cols, header)
    if fast is not None:
        return _plausible(p, fast, k)
    if not whole:
        lines = text.splitlines()
    return _plausible(p, _read_careful(p, lines, k, cols, header), k)


def _plausible(p: Path, trace: Trace, k: int) -> Trace:
    """A recording whose times are seconds from its start and that holds readings."""
    t, dl = trace.t_s, trace.delta_l_um
    finite = int(np.isfinite(dl).sum())
    if finite < MIN_SAMPLES:
        # a readable file that holds too little to be a recording of any program: it
        # does not fit (exit 6), as a recording shorter than its program does not
        raise RecordingError(f"{p}: {finite} reading(s) that are numbers (of {len(t)} rows); "
                             f"expected a recording of at least {MIN_SAMPLES}")
    if t[0] > 1e6:
        raise TraceError(f"{p}:{k + 2}: t_s starts at {t[0]:.6g} s, which looks like a clock "
                         f"or epoch timestamp; expected seconds from the start of the recording "
                         f"(subtract the first time)")
    if t[0] < -1.0:
        raise TraceError(f"{p}:{k + 2}: t_s starts at {t[0]:.6g} s; expected seconds from the "
                         f"start of the recording")
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate < MIN_RATE_HZ:
        raise TraceError(f"{p}: samples {1.0 / rate:.6g} s apart ({rate:.3g} Hz); a ballbar "
                         f"records at {MIN_RATE_HZ:g} Hz or more: are the times in t_s "
                         f"milliseconds? (write seconds)")
    stated = trace.header.get("sample_rate_hz")
    if stated is not None:
        try:
            stated_hz = float(stated)
        except ValueError:
            stated_hz = float("nan")
        if math.isfinite(stated_hz) and stated_hz > 0 and not 0.9 < rate / stated_hz < 1.1:
            raise TraceError(f"{p}: samples {1.0 / rate:.6g} s apart ({rate:.6g} Hz), but the "
                             f"header says sample_rate_hz: {_cell(stated)}; are the times in "
                             f"t_s in seconds?")
    return trace


def _read_careful(p: Path, lines: list[str], k: int, cols: list[str], header: dict) -> Trace:
    """Line by line, naming the first line that is not what the contract says."""
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
            raise TraceError(f"{p}:{j}: t_s {_cell(parts[it])} is not a number") from None
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
                raise TraceError(f"{p}:{j}: {unit} {_cell(cell)} is not a number") from None
            if math.isinf(lv):
                raise TraceError(f"{p}:{j}: {unit} {_cell(cell)} is not finite (a dropout is "
                                 f"empty or nan)")
            if abs(lv) > MAX_READING_UM:
                raise TraceError(f"{p}:{j}: {unit} {_cell(cell)} is {abs(lv) / 1e3:.3g} mm off "
                                 f"the bar's length; a ballbar reads within "
                                 f"+-{MAX_READING_UM / 1e3:g} mm (a dropout is empty or nan)")
        t[n], dl[n] = tv, lv
        seg[n] = parts[iseg].strip() if iseg is not None else ""
        ph[n] = parts[iph].strip() if iph is not None else ""
        n += 1
    if n == 0:
        raise TraceError(f"{p}: no data rows after the header")
    return Trace(t[:n], dl[:n], seg[:n], ph[:n], header)


def _read_fast(p: Path, body: str, rows: int, cols: list[str], header: dict) -> Trace | None:
    """The common case through pandas' C parser (``body``: the text of the ``rows`` rows
    after the header); None when anything is off, so the line-by-line reader finds and
    names the offending line."""
    import io

    import pandas as pd

    if len(set(cols)) != len(cols):
        return None
    unit = "delta_l_um" if "delta_l_um" in cols else "delta_l_mm"
    if not body.strip() or "#" in body:
        return None
    if body.count(",") != (len(cols) - 1) * rows:
        return None  # a short or long line somewhere: let the careful reader name it
    try:
        # (from bytes: from a text buffer an hour's recording took 0.15 GB more)
        df = pd.read_csv(io.BytesIO(body.encode()), header=None, names=cols, usecols=["t_s", unit],
                         dtype=float, engine="c", skip_blank_lines=False,
                         na_values=["", "nan", "NaN"], keep_default_na=False)
    except (ValueError, pd.errors.ParserError):
        return None
    t = df["t_s"].to_numpy(dtype=float)
    dl = df[unit].to_numpy(dtype=float) * (1.0 if unit == "delta_l_um" else 1000.0)
    if len(t) != rows or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        return None
    if np.isinf(dl).any() or (np.abs(np.nan_to_num(dl)) > MAX_READING_UM).any():
        return None  # the careful reader names the line
    if "segment" in cols or "phase" in cols:
        return None  # keep the labels: the careful reader does that
    no_labels = np.zeros(0, dtype=object)  # (an empty string per sample: 27 MB an hour)
    return Trace(t, dl, no_labels, no_labels, header)


def trace_csv(trace: Trace) -> str:
    """The simulator's file: header lines, ``t_s,delta_l_um,segment,phase`` (the
    trajectory's labels kept)."""
    lines = [f"# {k}: {v}" for k, v in trace.header.items()]
    lines.append("t_s,delta_l_um,segment,phase")
    n = len(trace.t_s)
    table = np.empty((n, 4), dtype=object)
    table[:, 0] = trace.t_s
    table[:, 1] = [("" if not np.isfinite(v) else f"{v:.4f}") for v in trace.delta_l_um]
    table[:, 2] = trace.segment
    table[:, 3] = trace.phase
    lines.append((("%.4f,%s,%s,%s\n" * n)[:-1]) % tuple(table.ravel()))
    return "\n".join(lines) + "\n"


def measured_csv(trace: Trace) -> str:
    """The instrument's file: header lines, ``t_s,delta_l_um`` only."""
    lines = [f"# {k}: {v}" for k, v in trace.header.items()]
    lines.append("t_s,delta_l_um")
    vals = ["" if not np.isfinite(v) else f"{v:.3f}" for v in trace.delta_l_um]
    ts = [f"{v:.3f}" for v in trace.t_s]
    lines.extend(f"{a},{b}" for a, b in zip(ts, vals))
    return "\n".join(lines) + "\n"
