"""Row bands of the pixel window (``--tile I/N``): one job's image computed as N partial EXRs,
assembled by :func:`.outputs.merge_exr`."""

from __future__ import annotations

__all__ = ["parse_tile", "tile_window"]


def parse_tile(tile) -> tuple:
    """``"I/N"`` (1-based, ``1 <= I <= N``) -> ``(I, N)``."""
    if isinstance(tile, (tuple, list)):
        i, n = (int(v) for v in tile)
    else:
        try:
            i_s, n_s = str(tile).split("/")
            i, n = int(i_s), int(n_s)
        except ValueError:
            raise ValueError(f"tile must look like I/N (e.g. 2/8), got {tile!r}") from None
    if not (n >= 1 and 1 <= i <= n):
        raise ValueError(f"tile {i}/{n}: need 1 <= I <= N")
    return i, n


def tile_window(window, tile) -> tuple:
    """Row band ``I`` of ``N`` of the pixel window (bands counted from the top row down, sizes
    differing by at most one row)."""
    i, n = parse_tile(tile)
    x0, y0, x1, y1 = window
    rows = y1 - y0
    if n > rows:
        raise ValueError(f"tile {i}/{n}: the window has only {rows} rows")
    top = y1 - (rows * (i - 1)) // n
    bottom = y1 - (rows * i) // n
    return x0, bottom, x1, top
