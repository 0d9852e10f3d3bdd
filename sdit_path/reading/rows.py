"""Per-sample values of a long program made at the samples asked for, never held whole.

An hour's program at 1 kHz has 3.4 million trajectory samples; each ``(n, 3)`` array of
its context is 80 MB.  Those that follow from others sample by sample (the bar
direction from the ball, the axis rates from the positions, the gains from their
coarser grid) are kept as the recipe: ``x[rows]``, ``x[rows, j]`` and ``x[:, j]`` make
the numbers asked for in the same arithmetic as the array held whole, so they are the
same numbers to the bit.  :func:`~sdit_path.reading.context.build_context` uses them on
programs longer than :data:`~sdit_path.reading.context.TALL_ROWS` only.
"""

from __future__ import annotations

import numpy as np

#: samples made at a time where a tall program's values are made over many of them (a
#: few MB a column)
BLOCK_ROWS = 1 << 16


def blocks(n: int, first: int = 0):
    """``(start, stop)`` of the blocks of :data:`BLOCK_ROWS` samples from ``first`` to ``n``."""
    for a in range(first, n, BLOCK_ROWS):
        yield a, min(a + BLOCK_ROWS, n)


def interp_rows(k: np.ndarray, values: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``values : (len(k), w)`` given at the increasing grid indices ``k``, linearly
    interpolated at ``x``: ``np.interp``'s arithmetic (the slope times the distance from
    the knot below, plus the value there; the last knot's value from the last knot on),
    every column at once, so the same numbers as ``np.interp`` column by column."""
    x = np.asarray(x, float)
    if len(k) < 2:
        return np.repeat(values[:1], len(x), axis=0)
    j = np.clip(np.searchsorted(k, x, side="right") - 1, 0, len(k) - 2)
    lo, hi = k[j].astype(float), k[j + 1].astype(float)
    out = (values[j + 1] - values[j]) / (hi - lo)[:, None] * (x - lo)[:, None] + values[j]
    out[x >= k[-1]] = values[-1]
    return out


def uniform_step(t: np.ndarray) -> float:
    """The step of the grid ``t`` if every step is equal (numpy's gradient then uses
    its uniform formula), else NaN."""
    dx = np.diff(t)
    return float(dx[0]) if len(dx) and (dx == dx[0]).all() else float("nan")


def gradient_rows(t: np.ndarray, step: float, f, idx: np.ndarray) -> np.ndarray:
    """``np.gradient(F, t, axis=0)[idx]`` for ``F : (n, m)`` in numpy's own arithmetic
    (second order inside, first order at the ends; ``step``: :func:`uniform_step` of
    ``t``), where ``f(i)`` gives the rows ``i`` of ``F``."""
    n = len(t)
    idx = np.asarray(idx)
    if len(idx):
        first, last = max(int(idx.min()) - 1, 0), min(int(idx.max()) + 1, n - 1)
        if last - first < 3 * len(idx):  # rows close together: the rows around them read once
            around = f(np.arange(first, last + 1))
            f = lambda i: around[i - first]  # noqa: E731
    here = f(idx)
    out = np.empty(here.shape)
    inner = (idx > 0) & (idx < n - 1)
    i = idx[inner]
    if np.isfinite(step):
        out[inner] = (f(i + 1) - f(i - 1)) / (2. * step)
    else:
        dx1, dx2 = (t[i] - t[i - 1]), (t[i + 1] - t[i])
        a = (-(dx2) / (dx1 * (dx1 + dx2)))[:, None]
        b = ((dx2 - dx1) / (dx1 * dx2))[:, None]
        c = (dx1 / (dx2 * (dx1 + dx2)))[:, None]
        out[inner] = a * f(i - 1) + b * here[inner] + c * f(i + 1)
    for end, hi, lo in ((0, 1, 0), (n - 1, n - 1, n - 2)):
        at = idx == end
        if at.any():
            dx = step if np.isfinite(step) else t[hi] - t[lo]
            out[at] = (f(np.array([hi])) - f(np.array([lo]))) / dx
    return out


class Rows:
    """``(n, m)`` values made where read.  ``x[rows]``, ``x[rows, j]``, ``x[rows, cols]``
    make those rows (:meth:`rows`); ``x[:, j]`` and ``x[:, cols]`` whole columns
    (:meth:`column`); ``np.asarray(x)`` the whole array."""

    ndim = 2
    dtype = np.dtype(float)

    def __init__(self, n: int, m: int):
        self.shape = (n, m)

    def rows(self, idx: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def column(self, j: int) -> np.ndarray:
        return self.rows(np.arange(self.shape[0]))[:, j]

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        r, c = key if isinstance(key, tuple) else (key, slice(None))
        every = isinstance(c, slice) and c == slice(None)
        if isinstance(r, slice) and r == slice(None) and not every:
            if np.ndim(c) == 0:
                return self.column(int(c))
            return np.column_stack([self.column(int(j)) for j in c])
        if isinstance(r, slice):
            r = np.arange(self.shape[0])[r]
        at = np.asarray(r)
        if at.dtype == bool:
            at = np.flatnonzero(at)
        vals = self._rows_in_blocks(at.ravel())
        if at.ndim == 0:
            vals = vals[0]
        return vals if every else vals[..., c]

    def _rows_in_blocks(self, idx: np.ndarray, block: int = BLOCK_ROWS) -> np.ndarray:
        """:meth:`rows`, a block of them at a time where many are asked for (each row is
        made from its own sample: the same numbers, without the temporaries of all of
        them at once)."""
        if len(idx) <= block:
            return self.rows(idx)
        out = np.empty((len(idx), self.shape[1]))
        for a in range(0, len(idx), block):
            out[a:a + block] = self.rows(idx[a:a + block])
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        whole = self._rows_in_blocks(np.arange(self.shape[0]))
        return whole if dtype is None else whole.astype(dtype)


class GridRows(Rows):
    """Columns given on the grid indices ``k`` and interpolated linearly at every
    sample (:func:`interp_rows`): each column the same numbers as
    ``np.interp(np.arange(n), k, values[:, j])``."""

    def __init__(self, n: int, k: np.ndarray, values: np.ndarray):
        super().__init__(n, values.shape[1])
        self.k, self.values = k, values

    def rows(self, idx):
        return interp_rows(self.k, self.values, idx)

    def column(self, j):
        return np.interp(np.arange(self.shape[0]), self.k, self.values[:, j])


class UnitRows(Rows):
    """The unit vectors ``(points - origin) / length`` (``length``: their norms, held)."""

    def __init__(self, points: np.ndarray, origin: np.ndarray, length: np.ndarray):
        super().__init__(*points.shape)
        self.points, self.origin, self.length = points, origin, length

    def rows(self, idx):
        return (self.points[idx] - self.origin) / self.length[idx][:, None]

    def column(self, j):
        return (self.points[:, j] - self.origin[j]) / self.length


class RateRows(Rows):
    """``np.gradient(values, t, axis=0)`` (:func:`gradient_rows`)."""

    def __init__(self, values: np.ndarray, t: np.ndarray):
        super().__init__(*values.shape)
        self.values, self.t, self.step = values, t, uniform_step(t)

    def rows(self, idx):
        if len(self.t) < 3:
            return np.zeros((len(idx), self.shape[1]))
        return gradient_rows(self.t, self.step, lambda i: self.values[i], idx)

    def column(self, j):
        if len(self.t) < 3:
            return np.zeros(self.shape[0])
        return np.gradient(self.values[:, j], self.t)


class RunEdge:
    """``(n,)``: per sample, ``values`` at the first (or last) sample of its run, the
    runs beginning at the samples ``starts``."""

    ndim = 1

    def __init__(self, values: np.ndarray, starts: np.ndarray, last: bool):
        self.values, self.starts = values, starts
        n = len(values)
        self.edge = np.r_[starts[1:] - 1, n - 1] if last else starts
        self.shape = (n,)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, idx) -> np.ndarray:
        at = np.asarray(np.arange(self.shape[0])[idx] if isinstance(idx, slice) else idx)
        run = np.searchsorted(self.starts, at, side="right") - 1
        return self.values[self.edge[run]]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        whole = self[np.arange(self.shape[0])]
        return whole if dtype is None else whole.astype(dtype)


class Labels:
    """``(n,)`` text labels (a sample's segment or phase) held as small codes into their
    distinct values: ``x[i]`` is the label, ``x[idx]`` an object array of them, as the
    object array held whole gives them."""

    ndim = 1

    def __init__(self, values: np.ndarray):
        import pandas as pd  # (hashes the labels; sorting millions of strings takes seconds)

        codes, names = pd.factorize(np.asarray(values, dtype=object))
        self.names = np.asarray(names, dtype=object)
        self.codes = codes.astype(np.min_scalar_type(max(len(self.names) - 1, 0)))
        self.shape = (len(values),)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, idx):
        return self.names[self.codes[idx]]

    def __eq__(self, other):  # type: ignore[override]
        """Per sample, whether its label is ``other`` (read from the codes)."""
        if isinstance(other, str):
            hit = np.flatnonzero(self.names == other)
            return self.codes == hit[0] if len(hit) else np.zeros(len(self), dtype=bool)
        return np.asarray(self) == other

    def __ne__(self, other):  # type: ignore[override]
        return ~np.asarray(self.__eq__(other), dtype=bool)

    __hash__ = None  # type: ignore[assignment]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        whole = self.names[self.codes]
        return whole if dtype is None else whole.astype(dtype)
