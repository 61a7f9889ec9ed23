"""The numba kernel registry of the census core: kernels are marked at import and compiled together.

Every per-pixel loop is a numba kernel compiled with ``cache=True``, so a fresh process loads
machine code from the cache instead of spending seconds recompiling. numba itself is imported on
the first call (``compile_all``), so importing the core costs no more than numpy + OpenCV.
numba's cache keys on a function's own file: kernels that call each other live in one module.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

_F = TypeVar("_F", bound=Callable[..., Any])

#: Kernels waiting for ``numba.njit``; compiled (or loaded from the cache) on first use.
_PENDING: list[tuple[Callable[..., Any], bool, bool, bool]] = []
_READY: list[bool] = []


def kernel(*, parallel: bool = False, fastmath: bool = True, inline: bool = False) -> Callable[[_F], _F]:
    """Mark a function as a numba kernel without importing numba at module import time.

    Kernels that test for NaN must pass ``fastmath=False``: fastmath lets LLVM assume no NaNs
    and fold ``np.isnan`` to False. ``inline`` has numba paste the kernel into its callers: a
    call between kernels is otherwise a real call, with reference counting on every array view
    passed, which costs more than a 128-disparity loop.
    """

    def mark(fn: _F) -> _F:
        _PENDING.append((fn, parallel, fastmath, inline))
        return fn

    return mark


def compile_all() -> None:
    """Swap every marked function for its numba dispatcher (once per process).

    The swap goes through each kernel module's globals, so kernels that call kernels, ``prange``
    and ``_popcount`` resolve to numba objects when numba compiles them; callers in other modules
    reach kernels as module attributes. ``cache=True`` keys on file and qualname, so the cache
    written by one process is reused by the next.
    """
    if _READY:
        return
    import numba

    popcount = _popcount_intrinsic()
    for fn, _, _, _ in _PENDING:
        module = vars(sys.modules[fn.__module__])
        module["prange"] = numba.prange
        if "_popcount" in module:
            module["_popcount"] = popcount
    for fn, parallel, fastmath, inline in _PENDING:
        vars(sys.modules[fn.__module__])[fn.__name__] = numba.njit(
            cache=True, parallel=parallel, fastmath=fastmath, nogil=True, inline="always" if inline else "never"
        )(fn)
    _READY.append(True)


def _popcount_intrinsic() -> Any:
    """``llvm.ctpop`` on uint64: one POPCNT instruction where the CPU has it (numba exposes none)."""
    from llvmlite import ir
    from numba import types
    from numba.core.extending import intrinsic

    @intrinsic
    def popcount(typingctx: Any, value: Any) -> Any:
        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            fn = builder.module.declare_intrinsic("llvm.ctpop", [ir.IntType(64)])
            return builder.call(fn, args)

        return types.uint64(types.uint64), codegen

    return popcount


def popcount_placeholder(v: np.uint64) -> np.uint64:
    """What ``_popcount`` is before ``compile_all`` swaps in the ctpop intrinsic."""
    return np.uint64(bin(int(v)).count("1"))
