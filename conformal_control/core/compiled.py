"""numba-compiled kernels, cached on disk, without the cache ever breaking a command.

Every compiled kernel of the package is decorated with ``njit(...)`` from here: numba's
``njit`` with ``cache=True``. The first use on a machine compiles for a few seconds and
writes the machine code beside the sources (``__pycache__``) or under
``$NUMBA_CACHE_DIR``; later processes load it. numba turns three states of that cache into
errors that stop any command; here each is a
:class:`~conformal_control.core.exceptions.CacheWarning`
(once per kind and process, naming the first function concerned) and a fallback:

* **no writable cache location** (a read-only install without a writable home; numba:
  "cannot cache function ...: no locator available") - the function is compiled in memory
  only, in every process (set ``NUMBA_CACHE_DIR`` to a writable folder to cache it);
* **an unreadable cache** (a truncated or corrupt index or data file: ``UnpicklingError``,
  ``EOFError``, ...) - the function's index file is deleted, the function compiled again
  and the cache written afresh;
* **a cache that cannot be written** (full disk, read-only folder) - the compiled function
  is used without being cached.

numba reads its cache files with :mod:`pickle`; they live in the package's own
``__pycache__`` (or the folder ``NUMBA_CACHE_DIR`` names), which nothing but numba writes.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Callable
from typing import Any, TypeVar, cast

from .exceptions import CacheWarning

_F = TypeVar("_F", bound=Callable[..., Any])

__all__ = ["njit"]


#: Kinds of cache problem already reported by this process ("locator", "load", "save").
_WARNED: set[str] = set()


def _warn(kind: str, what: str) -> None:
    if kind not in _WARNED:
        _WARNED.add(kind)
        warnings.warn(what, CacheWarning, stacklevel=3)


def _guard(dispatcher: Any, name: str) -> None:
    """Make the loads and saves of ``dispatcher``'s on-disk cache fail soft."""
    cache = getattr(dispatcher, "_cache", None)
    load = getattr(cache, "load_overload", None)
    save = getattr(cache, "save_overload", None)
    if cache is None or load is None or save is None:
        return
    cache_file = getattr(cache, "_cache_file", None)
    index = getattr(cache_file, "_index_path", None)

    def safe_load(sig: Any, target_context: Any) -> Any:
        try:
            return load(sig, target_context)
        except Exception as exc:  # a corrupt or truncated file: compile again
            if index:
                with contextlib.suppress(OSError):
                    os.unlink(index)  # the next save writes a fresh index
            _warn(
                "load",
                f"numba's cache of {name} is unreadable ({type(exc).__name__}: {exc}); "
                f"compiling it (and any other such function) again and rewriting the cache "
                f"({index or 'its index'})",
            )
            return None

    def safe_save(sig: Any, data: Any) -> None:
        try:
            save(sig, data)
        except Exception as exc:  # full disk, read-only folder: run without caching
            _warn(
                "save",
                f"numba's cache of {name} cannot be written ({type(exc).__name__}: {exc}); "
                "compiled code is used without being cached",
            )

    cache.load_overload = safe_load
    cache.save_overload = safe_save


def njit(**options: Any) -> Callable[[_F], _F]:
    """``numba.njit(cache=True, **options)`` whose cache problems are warnings, not errors.

    Use as ``jit = njit(nogil=True)`` then ``@jit`` on each kernel (see the module
    docstring for what happens when the cache cannot be used).
    """
    import numba

    def decorate(fn: _F) -> _F:
        name = f"{fn.__module__}.{fn.__qualname__}"
        try:
            dispatcher = numba.njit(cache=True, **options)(fn)
        except RuntimeError as exc:  # "cannot cache function ...: no locator available"
            if "cache" not in str(exc):
                raise
            _warn(
                "locator",
                f"numba cannot cache {name} ({exc}); it and the other compiled functions are "
                "compiled in memory in every process (set NUMBA_CACHE_DIR to a writable folder "
                "to cache them)",
            )
            # the dispatcher is called like the function (numba ships no type stubs)
            return cast("_F", numba.njit(cache=False, **options)(fn))
        _guard(dispatcher, name)
        return cast("_F", dispatcher)

    return decorate
