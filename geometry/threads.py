"""Run a stretch of small array work on one thread: OpenCV's thread pool and the BLAS numpy (and scipy) call.

On images of a few hundred pixels and least-squares systems of a few thousand rows by a few dozen columns,
handing the work to a thread pool costs more CPU (waking, spinning, waiting) than it saves; on a shared robot
computer (two cores, several processes) the CPU per call is what counts, and OpenBLAS's spinning threads made the
wall-pose fit cost several times its single-thread CPU. The previous thread counts are restored afterwards.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import cv2
import numpy as np  # noqa: F401  (loads numpy's BLAS before the controller looks for it)
from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_depth = 0  # nested uses are free: only the outermost one changes and restores the thread counts


def _blas() -> ThreadpoolController:
    """One controller for the process, made on first use (finding the loaded libraries takes a little while);
    it covers the BLAS libraries loaded by then, numpy's and scipy's included once they are imported."""
    global _controller
    if _controller is None:
        import scipy.linalg  # noqa: F401  (scipy ships a BLAS of its own; load it so it is limited too)

        _controller = ThreadpoolController()
    return _controller


@contextmanager
def single_threaded() -> Iterator[None]:
    """OpenCV and BLAS on one thread inside the block (re-entrant; not for use from several Python threads)."""
    global _depth
    if _depth > 0:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    _depth = 1
    try:
        with _blas().limit(limits=1, user_api="blas"):
            yield
    finally:
        _depth = 0
        cv2.setNumThreads(previous)
