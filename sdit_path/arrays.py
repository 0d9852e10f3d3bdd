"""Small helpers for the values inside frozen domain values and results."""

from __future__ import annotations

import numpy as np


def frozen(values, dtype=float) -> np.ndarray:
    """A read-only copy of ``values``: domain values never change after construction."""
    a = np.array(values, dtype=dtype)
    a.setflags(write=False)
    return a


class ReadOnlyDict(dict):
    """A dict that refuses changes, for the mappings inside frozen results (a
    ``MappingProxyType`` cannot cross to a worker process; this pickles as a dict does
    and ``json`` writes it as one)."""

    __slots__ = ()

    def _refuse(self, *args, **kwargs):
        raise TypeError("a read-only mapping of a frozen result")

    __setitem__ = __delitem__ = __ior__ = _refuse  # type: ignore[assignment]
    clear = pop = popitem = setdefault = update = _refuse  # type: ignore[assignment]

    def __reduce__(self):
        return (type(self), (dict(self),))

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self
