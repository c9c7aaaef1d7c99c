"""Compiled kernels that are compiled only when a process has enough work for them.

Every kernel of the package (the exact 2-D filter's step, the compiled engine's interval,
the plants' rollouts, ...) is plain Python on float64 arrays with scalar loops, compiled
with numba. Compiling is not free even from numba's cache: the first compiled call of a
process initialises LLVM and numba's registries (about a second; numba's ``arraymath``
imports ``scipy.linalg``), and every further kernel is loaded from disk. A single short run
(``conformal-control run --scene nexus_4`` needs about 0.2 s of control steps) pays more for
that than for its work. So :func:`kernel` defers it:

* ``auto`` (the default): a kernel runs as Python (its ``py_func``) until the process has
  spent :data:`BUDGET_S` seconds of CPU in interpreted kernels, then every kernel is compiled
  (:func:`conformal_control.core.compiled.njit` with the kernel's options: numba, loaded from its
  cache, whose problems are warnings) and the rest of the
  process runs compiled. Whatever the amount of work, the process spends at most about twice
  what the better of the two choices would have cost (the rent-or-buy argument: interpret
  until the rent paid equals the price of buying). Code that knows it has much work (the
  batch engine, sweeps, benchmarks) calls :func:`compile_now` first.
* ``CONFORMAL_CONTROL_JIT=always``: compile at the first call (numba as usual);
  ``CONFORMAL_CONTROL_JIT=never``: always interpret (slow; for debugging and coverage).

Both forms compute the same numbers: the same source, the same IEEE operations in the same
order (numba compiles without fast-math, so no reassociation or fused multiply-add), and
where numba and Python call different C functions for one name -- ``math.hypot`` is the C
library's in numba and CPython's own algorithm in Python -- the kernel names which one it
means (:func:`~conformal_control.families.cbf.pyhypot.c_hypot`,
:func:`~conformal_control.families.cbf.pyhypot.py_hypot`) and each form calls that one
(``python=``). ``tests/core/test_jit.py`` runs episodes of every compiled path in both forms and
compares them field by field.

Compiling replaces each kernel in the namespace of every loaded module of the package that
holds it by numba's dispatcher (so that compiled kernels call compiled kernels, as numba
needs); kernel objects held elsewhere forward to it.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

__all__ = ["BUDGET_S", "Kernel", "compile_now", "is_compiled", "kernel", "mode"]

F = TypeVar("F", bound=Callable[..., Any])

#: CPU seconds of interpreted kernels after which ``auto`` compiles (about what numba's
#: start-up and the loading of the cached kernels cost on a 2-core machine).
BUDGET_S = 0.6

_MODES = ("auto", "always", "never")


def mode() -> str:
    """The mode from ``$CONFORMAL_CONTROL_JIT`` (``auto``, ``always`` or ``never``)."""
    value = os.environ.get("CONFORMAL_CONTROL_JIT", "auto").strip().lower() or "auto"
    if value not in _MODES:
        raise ValueError(f"CONFORMAL_CONTROL_JIT must be one of {', '.join(_MODES)}, got {value!r}")
    return value


class _State:
    compiled = False
    spent = 0.0  # CPU seconds in outermost interpreted kernel calls
    lock = threading.RLock()
    local = threading.local()  # depth of interpreted kernel calls in this thread


_KERNELS: list[Kernel[Any]] = []


class Kernel(Generic[F]):
    """A function compiled by numba when the process compiles (see the module docstring).

    Calling it runs numba's dispatcher once compiled, else the Python function (or the
    ``python`` alternative given to :func:`kernel`). ``py_func`` is the Python original,
    as on a numba dispatcher.
    """

    def __init__(self, func: F, options: dict[str, Any], python: Callable[..., Any] | None):
        self.py_func = func
        self.options = options
        self.python = func if python is None else python
        self.dispatcher: Any = None
        self.__name__ = func.__name__
        self.__qualname__ = func.__qualname__
        self.__module__ = func.__module__
        self.__doc__ = func.__doc__
        self.__wrapped__ = func

    def __repr__(self) -> str:
        state = "compiled" if self.dispatcher is not None else "interpreted"
        return f"<kernel {self.__module__}.{self.__qualname__} ({state})>"

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        d = self.dispatcher
        if d is not None:
            return d(*args, **kwargs)
        local = _State.local
        depth = getattr(local, "depth", 0)
        if depth:  # inside an interpreted kernel: no accounting
            return self.python(*args, **kwargs)
        if _State.compiled or mode() == "always":
            compile_now()
            return self.dispatcher(*args, **kwargs)
        local.depth = 1
        t0 = time.process_time()
        try:
            return self.python(*args, **kwargs)
        finally:
            local.depth = 0
            _State.spent += time.process_time() - t0
            if _State.spent > BUDGET_S and mode() == "auto":
                compile_now()


def kernel(*, python: Callable[..., Any] | None = None, **options: Any) -> Callable[[F], F]:
    """Decorator: ``numba.njit(**options)``, applied when the process compiles.

    Parameters
    ----------
    python : callable, optional
        What the interpreted form calls instead of the function itself (same results, e.g.
        ``math.hypot`` for a compiled copy of CPython's ``math.hypot``).
    **options
        numba's ``njit`` options (``cache``, ``nogil``, ``inline``, ...).
    """

    def wrap(func: F) -> F:
        k: Kernel[F] = Kernel(func, dict(options), python)
        with _State.lock:
            _KERNELS.append(k)
            if _State.compiled:
                _compile(k)
                return k.dispatcher  # type: ignore[no-any-return]
        return k  # type: ignore[return-value]

    return wrap


def is_compiled() -> bool:
    """Whether this process runs its kernels compiled."""
    return _State.compiled


def _compile(k: Kernel[Any]) -> None:
    options = dict(k.options)
    if options.pop("cache", True):  # cached on disk, its problems warnings (compiled.njit)
        from .compiled import njit

        k.dispatcher = njit(**options)(k.py_func)
    else:
        import numba

        k.dispatcher = numba.njit(**options)(k.py_func)


def compile_now() -> None:
    """Compile every kernel now (from numba's cache when it holds them) and run compiled
    from here on, unless ``CONFORMAL_CONTROL_JIT=never``."""
    if _State.compiled or mode() == "never":
        return
    with _State.lock:
        if _State.compiled:
            return
        for k in _KERNELS:
            if k.dispatcher is None:
                _compile(k)
        swap = {id(k): k.dispatcher for k in _KERNELS}
        for module in list(sys.modules.values()):
            namespace = getattr(module, "__dict__", None)
            if not isinstance(namespace, dict):
                continue
            for attr, value in list(namespace.items()):
                if type(value) is Kernel and id(value) in swap:
                    namespace[attr] = swap[id(value)]
        _State.compiled = True
