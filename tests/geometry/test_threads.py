"""geometry.threads.single_threaded: OpenCV and BLAS on one thread inside, the previous counts back after."""

import cv2
import scipy.linalg  # noqa: F401  (its own BLAS, which single_threaded limits too)
from threadpoolctl import threadpool_info

from geometry.threads import single_threaded


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_one_thread_inside_and_the_counts_restored_after() -> None:
    cv_before, blas_before = cv2.getNumThreads(), _blas_threads()
    assert blas_before, "numpy's BLAS must be found, or the limit does nothing"
    with single_threaded():
        assert cv2.getNumThreads() == 1
        assert set(_blas_threads()) == {1}
        with single_threaded():  # nested: still one thread, and leaving it does not restore early
            pass
        assert cv2.getNumThreads() == 1
        assert set(_blas_threads()) == {1}
    assert cv2.getNumThreads() == cv_before
    assert _blas_threads() == blas_before


def test_restored_when_the_block_raises() -> None:
    cv_before = cv2.getNumThreads()
    try:
        with single_threaded():
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert cv2.getNumThreads() == cv_before
    with single_threaded():  # and usable again (the nesting depth went back to zero)
        assert cv2.getNumThreads() == 1
