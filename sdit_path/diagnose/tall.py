"""Tall models made where they are read: the columns of a long program's model are read
at the rows a fit samples (and summed a block of rows at a time), never held whole.

The alignment and the timing fit the recording with a model of some eighty columns on
every trajectory sample: 2 GB for an hour at 1 kHz, half of it the geometry's smooth
functions of the pose.  Those are interpolated from a coarser grid
(:func:`~sdit_path.reading.context.strided`), so any row of them is made from that grid
exactly as the whole column would be: :class:`Interpolated` holds the grid, and
:class:`RowModel` stands for the model, its interpolated parts made at the rows asked
for.  The rows are the same numbers as the model held whole; a product with the whole
model, and the sums over every row, the same to rounding.
"""

from __future__ import annotations

import numpy as np

from ..reading.rows import BLOCK_ROWS, interp_rows


class Interpolated:
    """``(n, w)`` columns given on the grid indices ``k`` (``values : (len(k), w)``,
    ``k`` increasing from 0 to n - 1), linearly interpolated at every row."""

    def __init__(self, n: int, k: np.ndarray, values: np.ndarray):
        self.k, self.values = k, values
        self.shape = (n, values.shape[1])
        self.ndim = 2

    def __getitem__(self, idx) -> np.ndarray:
        """The rows ``idx``: every column at once, in ``np.interp``'s arithmetic (its
        slope times the distance from the knot below, plus the value there; the last
        knot's value at the last row), so the same numbers, three times faster than
        column by column."""
        at = np.asarray(idx)
        out = interp_rows(self.k, self.values, at.ravel())
        return out[0] if at.ndim == 0 else out

    def spread(self) -> np.ndarray:
        """Each column's peak-to-peak over all rows: that of its grid values (a linear
        interpolation stays between them and passes through them)."""
        return np.ptp(self.values, axis=0) if len(self.values) else np.zeros(self.shape[1])

    def full(self) -> np.ndarray:
        return self[np.arange(self.shape[0])]


class Made:
    """``(n, w)`` columns made by ``rows(idx)`` at the rows asked for (an effect's columns
    at those trajectory samples: each row is made from the context at its own sample,
    so it is the same number whichever rows are asked for together)."""

    def __init__(self, n: int, rows, spread: np.ndarray | None = None):
        self.rows, self.known_spread = rows, spread
        self.shape = (n, rows(np.zeros(1, dtype=int)).shape[1])
        self.ndim = 2

    def __getitem__(self, idx) -> np.ndarray:
        at = np.asarray(idx)
        out = self.rows(at.ravel())
        return out[0] if at.ndim == 0 else out

    def blocks(self):
        """``(first row, rows)`` a block of :data:`BLOCK_ROWS` at a time."""
        for a in range(0, self.shape[0], BLOCK_ROWS):
            yield a, self.rows(np.arange(a, min(a + BLOCK_ROWS, self.shape[0])))

    def spread(self) -> np.ndarray:
        """Each column's peak-to-peak over all rows (a pass over them, unless known)."""
        if self.known_spread is not None:
            return self.known_spread
        lo = np.full(self.shape[1], np.inf)
        hi = np.full(self.shape[1], -np.inf)
        for _, vals in self.blocks():
            lo, hi = np.minimum(lo, vals.min(axis=0)), np.maximum(hi, vals.max(axis=0))
        return hi - lo if self.shape[0] else np.zeros(self.shape[1])

    def __matmul__(self, share: np.ndarray) -> np.ndarray:
        out = np.empty((self.shape[0],) + np.shape(share)[1:])
        for a, vals in self.blocks():
            out[a:a + len(vals)] = vals @ share
        return out

    def full(self) -> np.ndarray:
        return self[np.arange(self.shape[0])]


def is_tall(part) -> bool:
    """A part made where read (not an array)."""
    return isinstance(part, (Interpolated, Made, RowModel))


class RowModel:
    """A model ``(n, m)`` of ``parts`` (arrays, or :class:`Interpolated` made where read)
    of which the columns ``keep`` are the model, in order: ``model[idx]`` makes those
    rows, ``model @ beta`` the product part by part.  ``generic``: how many of the parts
    are the generic columns (:func:`~sdit_path.diagnose.align.generic_columns`)."""

    def __init__(self, parts: list, keep: np.ndarray, generic: int = 0):
        self.parts, self.generic = parts, generic
        self.n = parts[0].shape[0]
        widths = [p.shape[1] for p in parts]
        self.keeps = np.split(np.asarray(keep, bool), np.cumsum(widths)[:-1])
        self.shape = (self.n, int(np.sum(keep)))
        self.ndim = 2

    def generic_part(self) -> "RowModel":
        """The model of the generic parts alone (the same columns as
        ``generic_columns(ctx, expected)``: their spreads decide what they keep)."""
        keep = np.concatenate(self.keeps[:self.generic])
        return RowModel(self.parts[:self.generic], keep, self.generic)

    def __getitem__(self, idx) -> np.ndarray:
        at = np.asarray(idx)
        rows = at.ravel()
        out = np.empty((rows.size, self.shape[1]))
        col = 0
        for part, kept in zip(self.parts, self.keeps):
            w = int(kept.sum())
            if w == 0:
                continue
            vals = part[rows]
            out[:, col:col + w] = vals if kept.all() else vals[:, kept]
            col += w
        return out[0] if at.ndim == 0 else out

    def __matmul__(self, beta: np.ndarray) -> np.ndarray:
        """Each part times its share of ``beta`` (zero for its dropped columns), summed;
        an interpolated part's product is the interpolation of its grid's product (the
        same to rounding: the interpolation is linear)."""
        beta = np.asarray(beta, float)
        out = np.zeros((self.n,) + beta.shape[1:])
        at = 0
        for part, kept in zip(self.parts, self.keeps):
            w = int(kept.sum())
            if w == 0:
                continue
            share = np.zeros((part.shape[1],) + beta.shape[1:])
            share[kept] = beta[at:at + w]
            at += w
            if isinstance(part, Interpolated):
                grid = part.values @ share
                if grid.ndim == 1:
                    out += np.interp(np.arange(self.n), part.k, grid)
                else:
                    for c in range(grid.shape[1]):
                        out[:, c] += np.interp(np.arange(self.n), part.k, grid[:, c])
            else:
                out += part @ share
        return out

    def product_at(self, rows: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """``self[rows] @ beta``, a block of rows at a time."""
        out = np.empty(len(rows))
        for a in range(0, len(rows), BLOCK_ROWS):
            out[a:a + BLOCK_ROWS] = self[rows[a:a + BLOCK_ROWS]] @ beta
        return out

    def column_rms(self) -> np.ndarray:
        """``sqrt(mean(X * X, axis=0))``, summed a block of rows at a time."""
        total = np.zeros(self.shape[1])
        for a in range(0, self.n, BLOCK_ROWS):
            rows = self[np.arange(a, min(a + BLOCK_ROWS, self.n))]
            total += np.einsum("ij,ij->j", rows, rows)
        return np.sqrt(total / self.n)

    def block_means(self, per: int, count: int, scale: np.ndarray) -> np.ndarray:
        """``(count, m)``: the means of ``X / scale`` over the row blocks ``[i per, (i + 1)
        per)``."""
        out = np.empty((count, self.shape[1]))
        step = max(1, BLOCK_ROWS // per)
        for a in range(0, count, step):
            b = min(a + step, count)
            rows = self[np.arange(a * per, b * per)] / scale
            out[a:b] = rows.reshape(b - a, per, -1).mean(axis=1)
        return out
