"""oneshot/host.py: the BLAS thread count is really set, and the previous count comes back. (What
`machine()` reports is checked against /proc/cpuinfo and the installed NumPy in tests/test_train.py,
on the figure `python -m oneshot.benchmark maml` prints.)"""
import os

import pytest

from oneshot.tools import host


def test_blas_threads_returns_the_previous_count_and_really_sets_it():
    before = host.blas_threads(1)
    if before is None:
        pytest.skip("NumPy's BLAS is not an OpenBLAS that oneshot.tools.host can reach")
    # Set a count other than the one found, so that reading it back shows the call changed something.
    other = 1 if before != 1 else 2
    if other > (os.cpu_count() or 1):
        host.blas_threads(before)
        pytest.skip("one core and one BLAS thread: no other count to set")
    try:
        host.blas_threads(other)
        seen = host.blas_threads(other)
    finally:
        restored_from = host.blas_threads(before)
    assert isinstance(before, int) and before >= 1
    assert seen == other and restored_from == other
    assert host.blas_threads(before) == before
