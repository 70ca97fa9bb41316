"""The bounded memories kincal keeps per structure (joint-screw terms, layout blocks, column plans, ...): one
insertion rule for all of them."""

from __future__ import annotations


def remember(cache: dict, key, value, limit: int):
    """``cache[key] = value`` with the oldest entry dropped first when ``cache`` holds ``limit`` already; returns
    ``value``. Tolerant of another thread (a Dask worker's) adding or dropping entries meanwhile: the worst case is
    a cache briefly one entry over or under its limit, never an error."""
    if len(cache) >= limit:
        try:
            cache.pop(next(iter(cache)), None)
        except (StopIteration, RuntimeError):  # emptied, or changed size while read, by another thread
            pass
    cache[key] = value
    return value
