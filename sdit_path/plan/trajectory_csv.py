"""The trajectory file of a plan: CSV with ``# key: value`` lines first, one row per
sample of :class:`~sdit_path.timing.trajectory.Samples`; written by ``plan``, read back by
every command that reads a plan (gzip-compressed in the plan directory)."""

from __future__ import annotations

import warnings

import numpy as np

from ..timing.trajectory import Samples


def to_csv(samples: Samples, header: dict[str, str]) -> str:
    """CSV text with ``# key: value`` lines first; numbers fixed-point."""
    lines = [f"# {k}: {v}" for k, v in header.items()]
    cols = (["t_s", "ball_x_mm", "ball_y_mm", "ball_z_mm"]
            + [f"axis_{n}_{u}" for n, u in zip(samples.axis_names, samples.axis_units)]
            + ["segment", "phase", "path_speed_mm_per_s"])
    lines.append(",".join(cols))
    num = np.column_stack([np.round(samples.t_s, 4), np.round(samples.ball_mm, 8),
                           np.round(samples.axes, 10)]) + 0.0
    n, k = num.shape
    table = np.empty((n, k + 3), dtype=object)
    table[:, :k] = num
    table[:, k] = samples.segment
    table[:, k + 1] = samples.phase
    table[:, k + 2] = samples.speed_mm_per_s
    # axis values carry 10 decimals so that third differences at 1 kHz resolve jerk
    # (rounding noise 4 * 0.5e-10 / 1e-9 = 0.2 unit/s^3)
    row = ",".join(["%.4f"] + ["%.8f"] * 3 + ["%.10f"] * (k - 4) + ["%s", "%s", "%.5f"]) + "\n"
    lines.append((row * n)[:-1] % tuple(table.ravel()))
    return "\n".join(lines) + "\n"


def read_csv_file(path) -> Samples:
    """Read a trajectory file from disk (pandas' C parser straight from the file)."""
    import pandas as pd

    from ..errors import SditError

    try:
        # a number column holding text ("nan" is not read as a value here) is named by
        # the one-line error below; pandas' warning of mixed types must not print first
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.DtypeWarning)
            df = pd.read_csv(path, comment="#", dtype={"segment": str, "phase": str},
                             keep_default_na=False, engine="c")
    except (ValueError, pd.errors.ParserError) as exc:
        raise SditError(f"{path}: not a trajectory file written by sdit-path plan ({exc})") from None
    return _samples(df, list(df.columns), str(path))


def _samples(df, cols: list[str], source: str) -> Samples:
    from ..errors import SditError

    axis_cols = [c for c in cols if c.startswith("axis_")]
    names = tuple(c.split("_")[1] for c in axis_cols)
    units = tuple(c.split("_")[2] for c in axis_cols)
    need = ["t_s", "ball_x_mm", "ball_y_mm", "ball_z_mm"] + axis_cols + ["path_speed_mm_per_s"]
    try:
        # each field an array of its own (views into one table of every number keep it
        # all alive as long as any is read: an hour's 0.24 GB held for its times and ball)
        t, ball, axes, speed = (df[c].to_numpy(dtype=float, copy=True)
                                for c in (need[0], need[1:4], axis_cols, need[-1]))
        seg, ph = df["segment"].to_numpy(dtype=object), df["phase"].to_numpy(dtype=object)
    except (ValueError, KeyError) as exc:
        raise SditError(f"{source}: not a trajectory file written by sdit-path plan ({exc})") from None
    return Samples(t, np.ascontiguousarray(ball), np.ascontiguousarray(axes), seg, ph, speed,
                   names, units)


def read_csv(text: str, source: str = "<trajectory>") -> Samples:
    """Read a trajectory file written by :func:`to_csv` back into :class:`Samples`."""
    from ..errors import SditError

    import io

    head_end = 0
    header = None
    for line in io.StringIO(text):
        head_end += len(line)
        if line.strip() and not line.startswith("#"):
            header = line.strip()
            break
    if header is None:
        raise SditError(f"{source}: empty trajectory file")
    cols = header.split(",")
    import pandas as pd  # its C parser reads a one-hour trajectory in seconds

    try:
        df = pd.read_csv(io.StringIO(text[head_end:]), header=None, names=cols, comment="#",
                         dtype={"segment": str, "phase": str}, keep_default_na=False,
                         engine="c")
    except (ValueError, pd.errors.ParserError) as exc:
        raise SditError(f"{source}: not a trajectory file written by sdit-path plan ({exc})") from None
    return _samples(df, cols, source)
