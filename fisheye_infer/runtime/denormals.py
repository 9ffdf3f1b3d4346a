"""Denormal floats flushed to zero on the calling thread while a model runs.

    with flushed_denormals():
        outputs = session.run(None, feeds)

An attention's softmax (FisheyePETR's decoder: 100 queries against 1,600 image positions per head)
gives most positions weights below float32's smallest normal number, about 1.2e-38. On x86 CPUs an
instruction that reads or writes such a denormal number leaves the vector units' fast path (a
softmax over large logits runs about ten times slower, and so do the products that read its
weights), unless the thread's MXCSR register sets flush-to-zero (FTZ: denormal results become 0)
and denormals-are-zero (DAZ: denormal inputs read as 0). A weight below 1.2e-38 changes no output
of a float32 network, so the flushed run gives the same outputs.

ONNX Runtime sets both bits on a session's worker threads when its options ask
(``session.set_denormal_as_zero``, which ``session_options`` sets); the calling thread computes its
share of every parallel kernel (all of it at one thread), and ONNX Runtime sets the bits there only
once, for good, on the thread that builds the process's first session. ``flushed_denormals`` sets
the two bits on the calling thread for the duration of a ``with`` block and restores the thread's
previous floating-point environment after it, through the C library's ``fegetenv``/``fesetenv``:
``Detector`` runs its session inside it, and ``create_session`` builds one inside it, so that the
bits stay off on the caller's thread outside the runs. It acts on Linux x86-64 (glibc and musl lay
out ``fenv_t`` alike: the x87 environment, then MXCSR); elsewhere it does nothing and ``FLUSHES``
is False.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform
import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["FLUSHES", "flushed_denormals"]

#: MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6) bits.
_MXCSR_FLUSH = 0x8040


class _Environment(ctypes.Structure):
    """``fenv_t`` of Linux x86-64: the x87 environment (28 bytes), then MXCSR."""

    _fields_ = [("x87", ctypes.c_uint8 * 28), ("mxcsr", ctypes.c_uint32)]


def _load_libm() -> ctypes.CDLL | None:
    if sys.platform != "linux" or platform.machine() not in ("x86_64", "AMD64"):
        return None
    found = ctypes.util.find_library("m")  # glibc's libm; musl keeps the fenv functions in libc, already loaded
    try:
        libm = ctypes.CDLL(found) if found else ctypes.CDLL(None)
    except OSError:
        return None
    if not (hasattr(libm, "fegetenv") and hasattr(libm, "fesetenv")):
        return None
    for name in ("fegetenv", "fesetenv"):
        getattr(libm, name).argtypes = [ctypes.POINTER(_Environment)]
        getattr(libm, name).restype = ctypes.c_int
    return libm


_LIBM = _load_libm()
#: Whether ``flushed_denormals`` sets the bits on this platform.
FLUSHES = _LIBM is not None


@contextmanager
def flushed_denormals() -> Iterator[None]:
    """Flush-to-zero and denormals-are-zero on the calling thread inside the block (Linux x86-64), the
    thread's floating-point environment restored after it.

    Yields:
        None: Run the model inside the block.
    """
    if _LIBM is None:
        yield
        return
    saved = _Environment()
    if _LIBM.fegetenv(ctypes.byref(saved)) != 0:
        yield
        return
    flushed = _Environment.from_buffer_copy(saved)
    flushed.mxcsr |= _MXCSR_FLUSH
    _LIBM.fesetenv(ctypes.byref(flushed))
    try:
        yield
    finally:
        _LIBM.fesetenv(ctypes.byref(saved))
