"""What a process asks of the machine, in one place: fewer page faults from malloc, and the number of
BLAS threads. Both are no-ops where the C library or NumPy's BLAS does not offer them.

Why the BLAS thread count matters: during meta-training the matrix products are small (40 output
channels), and OpenBLAS's threads spin while they wait for work. With two shard processes on two
cores, two spinning BLAS threads each made a meta-iteration 5x slower than one thread each; a
notebook cell that meta-trains for a few iterations ran 36 s with 2 BLAS threads and 4.7 s with 1
while the other core was busy (docs/results.md).
"""
import ctypes
import glob
import os

import numpy as np


def tune_malloc():
    """Keep freed memory in the process instead of returning it to the OS after every array.

    The network allocates and frees multi-megabyte arrays thousands of times per meta-iteration;
    glibc hands each back to the OS and page-faults it in again (~1000 faults per forward pass).
    Raising the mmap and trim thresholds stops that (measured: `python -m oneshot.benchmark maml`).
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-1, 1 << 30)        # M_TRIM_THRESHOLD
        libc.mallopt(-3, 1 << 30)        # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass


def _openblas():
    """(get, set) of the thread count of NumPy's bundled OpenBLAS, or None where it cannot be found."""
    folder = os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs")
    for path in glob.glob(os.path.join(folder, "*openblas*")):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix, suffix in (("scipy_openblas", "64_"), ("scipy_openblas", ""), ("openblas", "")):
            get, set_ = f"{prefix}_get_num_threads{suffix}", f"{prefix}_set_num_threads{suffix}"
            if hasattr(lib, get) and hasattr(lib, set_):
                return getattr(lib, get), getattr(lib, set_)
    return None


def blas_threads(n):
    """Set the number of BLAS threads of this process to n. Returns the previous count, or None
    where NumPy's BLAS is not an OpenBLAS this can reach (then nothing changes)."""
    blas = _openblas()
    if blas is None:
        return None
    get, set_ = blas
    before = get()
    set_(int(n))
    return before
