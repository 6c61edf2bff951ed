"""Compressed sparse row (CSR) lists: the ragged "polygons of a tile", "volumes of a fragment" of the core."""

from __future__ import annotations

import numpy as np

__all__ = ["expand"]


def expand(owner: np.ndarray, ptr: np.ndarray, values: np.ndarray):
    """For every ``owner[b]``, all of ``values[ptr[o]:ptr[o+1]]``.

    Args:
        owner: (B,) row of every item; ptr: (R+1,) row starts; values: (ptr[-1],) the lists' entries.
    Returns:
        ``b (P,), value (P,)``: the item each entry belongs to (in order) and the entry.
    """
    n = ptr[owner + 1] - ptr[owner]
    b = np.repeat(np.arange(len(owner)), n)
    pos = np.arange(len(b)) - np.repeat(np.cumsum(n) - n, n) + np.repeat(ptr[owner], n)
    return b, values[pos]
