"""Compiled kernels (numba): one decorator for every kernel of the package, with numba's cache where it works.

numba keeps compiled kernels in ``__pycache__`` beside the source, else in the user's cache folder (``~/.cache``,
``NUMBA_CACHE_DIR``). Installed as users have it (site-packages read-only, no writable home, another user), neither
is writable and ``numba.njit(cache=True)`` raised ``RuntimeError: cannot cache function ...: no locator available``
at import: the package did not import at all. :func:`njit` compiles without the cache there instead (each run
compiles again, a few seconds), said once per process in a warning that names ``NUMBA_CACHE_DIR``. Nothing
process-wide is changed (no environment variable, no numba setting).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numba

logger = logging.getLogger(__name__)
_said = False


def njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)``, or ``cache=False`` where numba finds no writable place for its cache
    (one warning per process)."""
    def compiled(func: Callable[..., Any]) -> Any:
        global _said
        try:
            return numba.njit(cache=True, **options)(func)
        except RuntimeError as exc:
            if "no locator available" not in str(exc):
                raise
            if not _said:
                _said = True
                logger.warning("numba's cache: no writable place for compiled kernels (the package folder and the "
                               "user's cache folder are read-only); they are compiled on every run: set "
                               "NUMBA_CACHE_DIR to a writable folder to keep them")
            return numba.njit(cache=False, **options)(func)
    return compiled
