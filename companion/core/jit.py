"""Compiled hot loops of the pure core (numba), compiled or loaded on first use.

A function registered with :func:`lazy` is compiled for its one signature the first time
it is asked for, or loaded from numba's disk cache (``cache=True``: next to its source
file, else in the user's cache directory). Only the first process after an install or a
change of the file compiles (about 2 s per function); later processes import numba and
load the machine code (0.5 to 1 s in all on a quiet 2-core machine). numba is imported on
first use only, so commands that never plan do not pay for it; the real-time planning
process and the setpoint stream call :func:`warm_up` before their first request.

The compiled functions do the operations of the Python or numpy code they replace in
the same order, so their results are the same bits (each is tested so); without numba
(:func:`available` false) that code runs instead.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
from types import FunctionType, ModuleType
from typing import Callable

logger = logging.getLogger(__name__)

#: Whether numba is installed (then the registered functions are compiled, if it imports).
COMPILED = importlib.util.find_spec("numba") is not None

_REGISTERED: list[Callable[[], Callable]] = []


@functools.cache
def available() -> bool:
    """Whether the compiled functions can be used: numba installed and importing (imported here, once).

    A numba that does not import (for example one built for another numpy) is logged once
    and the Python and numpy code runs instead, with the same results.
    """
    if not COMPILED:
        return False
    try:
        import numba  # noqa: F401
    except ImportError as exc:
        logger.warning("numba does not import (%s): the planner runs its numpy code instead", exc)
        return False
    return True


def lazy(signature: Callable[[ModuleType], object]) -> Callable[[Callable], Callable[[], Callable]]:
    """Decorator: ``fn`` becomes a getter of its compiled version for one signature.

    ``signature(numba.types)`` builds the signature (so that numba is imported only when
    compiling); :func:`readonly` declares an input array that may be read-only. The getter
    compiles (or loads) once per process and returns the compiled function; calling it with
    arrays of another type or layout raises ``TypeError``.
    """

    def register(fn: Callable) -> Callable[[], Callable]:
        @functools.cache
        def compiled() -> Callable:
            import numba

            return numba.njit(signature(numba.types), cache=True, nogil=True, error_model="numpy")(_with_inlined(fn))

        compiled.py_func = fn    # the Python original (tests compare the two)
        _REGISTERED.append(compiled)
        return compiled

    return register


def inline(fn: Callable) -> Callable:
    """Decorator: a helper of the compiled functions of its own module, inlined into each.

    Compiled, a registered function calls the helper's numba version, inlined where it is
    called (the same operations as written out there, so the same bits); from Python (the
    fallback without numba, the tests) the helper is the plain function. Keep a helper in
    the module of the functions calling it: numba's disk cache is renewed when that
    module's file changes, not when another module does.
    """
    fn.__jit_inline__ = True
    return fn


def _with_inlined(fn: Callable) -> Callable:
    """``fn``, or a copy of it whose globals hold the numba versions of its module's :func:`inline` helpers."""
    import numba

    helpers = {name: numba.njit(inline="always", error_model="numpy")(value)
               for name, value in fn.__globals__.items() if getattr(value, "__jit_inline__", False)}
    if not helpers:
        return fn
    copy = FunctionType(fn.__code__, {**fn.__globals__, **helpers}, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__, copy.__doc__ = fn.__qualname__, fn.__doc__
    return copy


def readonly(types: ModuleType, ndim: int) -> object:
    """numba's type of a C-contiguous float64 input array of ``ndim`` dimensions, read-only or not."""
    return types.Array(types.float64, ndim, "C", readonly=True)


def warm_up() -> None:
    """Compile or load every registered function now (a no-op without numba or when already done)."""
    if available():
        for compiled in _REGISTERED:
            compiled()
