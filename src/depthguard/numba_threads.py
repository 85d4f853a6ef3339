"""numba's per-thread settings without giving the GIL away (issue 29).

``numba.get_num_threads``, ``numba.set_num_threads`` and ``numba.parallel_chunksize`` are, when
called from Python, ctypes calls into numba's threading layer, and ctypes releases the GIL for
each and takes it back afterwards. A release costs nothing on an idle interpreter; in a
real-time run, where the simulator, the camera workers, the fusion, the sinks and the control
loop share one GIL, each retake can wait behind the other threads (the fusion's query made nine
such calls per build: ``perf`` uprobes on CPython's ``take_gil``, ur3-cell, 2026-11-27).
:func:`thread_settings` reads and sets both in one compiled call that keeps the GIL.

The compiled call reaches the layer's functions by the names numba gives them to LLVM, with the
types of numba's own parallel lowering (``numba.parfors.parfor_lowering``), so that it is cached
on disk like every kernel (numba's in-kernel ``set_num_threads`` goes through a ctypes pointer,
which numba cannot cache: a second of compilation in every process).
"""

from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.ufunc.parallel import NUM_THREADS, _launch_threads

__all__ = ["thread_settings", "NUMBA_NUM_THREADS"]

NUMBA_NUM_THREADS = NUM_THREADS       # the threads numba launched (numba.config.NUMBA_NUM_THREADS)

def _layer_function(builder, name: str, ret, args):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, args), name)


@intrinsic
def _get_num_threads(typingctx):
    def codegen(context, builder, signature, args):
        return builder.call(_layer_function(builder, "get_num_threads", ir.IntType(types.intp.bitwidth), []), [])
    return types.intp(), codegen


@intrinsic
def _set_num_threads(typingctx, n):
    def codegen(context, builder, signature, args):
        count = builder.trunc(args[0], ir.IntType(32))           # the layer's C int
        builder.call(_layer_function(builder, "set_num_threads", ir.VoidType(), [ir.IntType(32)]), [count])
        return context.get_dummy_value()
    return types.none(types.int64), codegen


@intrinsic
def _get_chunksize(typingctx):
    def codegen(context, builder, signature, args):
        return builder.call(_layer_function(builder, "get_parallel_chunksize", ir.IntType(types.uintp.bitwidth), []),
                            [])
    return types.uintp(), codegen


@intrinsic
def _set_chunksize(typingctx, n):
    def codegen(context, builder, signature, args):
        uintp = ir.IntType(types.uintp.bitwidth)
        builder.call(_layer_function(builder, "set_parallel_chunksize", ir.VoidType(), [uintp]), [args[0]])
        return context.get_dummy_value()
    return types.none(types.int64), codegen


@njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def _settings(threads, chunksize, limit):
    before = (_get_num_threads(), int(_get_chunksize()))
    if threads > limit:
        raise ValueError("the number of threads must be at most NUMBA_NUM_THREADS")
    if threads > 0:
        _set_num_threads(threads)
    if chunksize >= 0:
        _set_chunksize(chunksize)
    return before


def thread_settings(threads: int, chunksize: int) -> tuple[int, int]:
    """Set the calling thread's numba thread count (``threads`` > 0; 0 leaves it) and parallel
    chunk size (``chunksize`` >= 0; -1 leaves it), as ``numba.set_num_threads`` and
    ``numba.set_parallel_chunksize`` would; returns the ``(threads, chunksize)`` in force
    before, to hand back to restore them. ``threads`` above ``NUMBA_NUM_THREADS``: ``ValueError``."""
    if not _launched:
        _launch()
    return _settings(threads, chunksize, NUM_THREADS)


_launched = False


def _launch() -> None:
    """numba's threading layer started, its functions known to LLVM by name: the cached
    :func:`_settings` is linked by them (once, at the first call: not at import)."""
    global _launched
    _launch_threads()
    _launched = True
