"""The machine, in one place: what a process asks of it (fewer page faults from malloc, the number of
BLAS threads; no-ops where the C library or NumPy's BLAS does not offer them) and what it is (the CPU,
NumPy's BLAS and SIMD level, peak memory), which every benchmark figure records; and that a worker
process ends with the process that started it (`die_with_parent`).

Why the BLAS thread count matters: during meta-training the matrix products are small (40 output
channels), and OpenBLAS's threads spin while they wait for work. With two shard processes on two
cores, two spinning BLAS threads each made a meta-iteration 5x slower than one thread each; while
two trainings ran, notebook 3 took 36 s with 2 BLAS threads and 4.7 s with 1 (docs/results.md).
"""
import ctypes
import glob
import os
import resource
import signal
import threading
import time

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


PR_SET_PDEATHSIG = 1                    # linux/prctl.h


def die_with_parent(parent, sig=signal.SIGKILL):
    """End this process when its parent (pid `parent`) dies, even by kill -9, instead of living on,
    reparented, blocked on a pipe: a worker process calls it first. On Linux the kernel sends `sig`
    (prctl PR_SET_PDEATHSIG; SIGTERM lets a handler clean up first); elsewhere a daemon thread checks
    the parent's pid every second and sends it. If the parent has died already, exit at once."""
    try:
        if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig)) == 0:
            if os.getppid() != parent:   # the parent died before prctl took effect
                os._exit(1)
            return
    except (OSError, AttributeError):
        pass

    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os.kill(os.getpid(), sig)
    threading.Thread(target=watch, daemon=True).start()


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


def machine():
    """What the figures were measured on: CPU model, cores, NumPy and its BLAS, and the widest SIMD
    extensions NumPy found. Float32 results differ in the last bits between CPUs whose BLAS and NumPy
    pick different kernels (e.g. with or without AVX-512), and training amplifies such differences
    (docs/results.md)."""
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    try:
        config = np.show_config(mode="dicts")
    except TypeError:                                    # NumPy < 1.26 only prints its config
        config = {}
    blas = config.get("Build Dependencies", {}).get("blas", {})
    return {"cpu": cpu, "cores": os.cpu_count(), "numpy": np.__version__,
            "blas": f"{blas.get('name', '?')} {blas.get('version', '?')}",
            "simd": config.get("SIMD Extensions", {}).get("found", [])}


def peak_memory_mb():
    """Peak resident memory (MB) of this process and of the largest of its finished worker processes."""
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)
