"""A sweep of independent runs through any `concurrent.futures.Executor`, resumable, with one CSV row
per finished run (the machinery of `oneshot.experiments.fig2`; `summary` summarises and draws the rows).

    rows = sweep(runs, "results/", "work/", context, executor=None, run_fn=run_one)

Each run is `run_fn(spec, run_dir, context) -> {"successes", "trials", ...}`, called in a worker of the
executor (a process pool by default; a thread pool; Dask's `Client.get_executor()`): a module-level
function, since it is pickled, that writes only inside its own `run_dir`, where it keeps whatever it
needs to resume (it may read its siblings: Figure 2's longer lines continue another run). results/runs.csv is rewritten atomically after every finished run, and the row is
also kept in work/<run id>/row.json: a run counts as done only when runs.csv holds the row its own work
folder produced, so rows this work folder did not produce (committed results, another machine's) are
never mistaken for a reproduction; they are run again, and replaced. Running the same sweep again
resumes it: done runs are skipped, interrupted ones continue from what their folders hold.
"""
import concurrent.futures
import contextlib
import fcntl
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback

from tqdm import tqdm

from oneshot.experiments.rows import ROW_FILE, COLUMNS, read_rows, row_id, row_of, row_order, write_rows
from oneshot.tools.files import atomic_write, open_read, open_write
from oneshot.tools.host import die_with_parent


# --- one run, in a worker ----------------------------------------------------------------------------

def execute(run_fn, spec, run_dir, context):
    """Run `run_fn` on one spec (in a worker) and return its runs.csv row, also written to
    run_dir/row.json (the proof that this work folder produced it). On an error, the traceback is
    written to run_dir/error.txt and the error raised again."""
    os.makedirs(run_dir, exist_ok=True)
    error_file = os.path.join(run_dir, "error.txt")
    t0 = time.perf_counter()
    if _stopping:                              # the sweep is stopping this worker: start nothing more
        raise KeyboardInterrupt("the sweep is stopping")
    try:
        row = row_of(spec, run_fn(spec, run_dir, context), time.perf_counter() - t0)
    except BaseException:
        if _stopping:                          # stopped by the sweep: the run has saved what it had
            raise
        with open_write(error_file, "w") as f:
            f.write(traceback.format_exc())
        raise
    with atomic_write(os.path.join(run_dir, ROW_FILE)) as f:
        f.write(json.dumps(row, sort_keys=True).encode("utf-8"))
    if os.path.exists(error_file):             # an earlier attempt failed; this one did not
        os.remove(error_file)
    return row


def produced(row, work_dir):
    """Did this work folder produce this row? (its run's folder holds the same row in row.json)"""
    path = os.path.join(work_dir, row_id(row), ROW_FILE)
    if not os.path.isfile(path):
        return False
    try:
        with open_read(path, "r") as f:
            kept = json.loads(f.read())
    except (ValueError, OSError):
        return False
    return {k: kept.get(k) for k in COLUMNS} == {k: row[k] for k in COLUMNS}


def done_rows(results_dir, work_dir, keep_rows=False):
    """{run id: row} of results_dir/runs.csv's rows that count as done (see `sweep`): those work_dir
    produced, or every row with keep_rows."""
    rows = read_rows(os.path.join(results_dir, "runs.csv"))        # runs.csv is replaced whole: safe to read
    return {row_id(row): row for row in rows if keep_rows or produced(row, work_dir)}


_stopping = False                              # set in a pool worker the sweep is stopping


def _worker_start(parent):
    """In each pool worker: end with the sweep however it ends, leave Ctrl-C to the sweep (which
    stops the workers with SIGTERM), and treat SIGTERM as Ctrl-C, so that a run saves its checkpoint
    and the worker starts no other (`execute`). Its progress bars lock with a thread lock, not tqdm's
    default of a named semaphore: a worker killed at a second Ctrl-C leaves none behind (which Python's
    resource tracker would report at the sweep's exit)."""
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _stop_worker)
    tqdm.set_lock(threading.RLock())


def _stop_worker(signum, frame):
    global _stopping
    _stopping = True
    raise KeyboardInterrupt


# --- the sweep -------------------------------------------------------------------------------------------

class SweepLocked(RuntimeError):
    """Another sweep is running in the same work or results folder."""


def _lock(folder, name, stack):
    """Hold an exclusive lock on folder/name for the rest of `stack` (SweepLocked if another process has it)."""
    os.makedirs(folder, exist_ok=True)
    lock = stack.enter_context(open_write(os.path.join(folder, name), "w"))
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)   # released when the file closes
    except BlockingIOError:
        raise SweepLocked(f"another sweep is running with {folder} (it holds {lock.name})") from None


def sweep(runs, results_dir, work_dir, context, run_fn, executor=None, progress=True, workers=2, stop_after=30.0,
          keep_rows=False):
    """Perform every run of `runs` (RunSpecs) not yet done; return the rows of the done ones (dicts over
    COLUMNS, in runs.csv's order). A run is done when results_dir/runs.csv holds the row that its own
    folder work_dir/<run id> produced (`produced`).

    Runs are submitted to `executor` (any concurrent.futures.Executor; default: a process pool of
    `workers` spawned processes, which end with this one) as `run_fn(spec, work_dir/<run id>, context)`.
    Each finished run adds its row and runs.csv is rewritten atomically; a run that raises is named on
    stderr (traceback in its folder's error.txt) and left out, so the next sweep runs it again. Rows of
    other runs are kept in the file but not returned; rows of these runs that the work folder did not
    produce are run again and replaced. A sweep with runs to do holds locks on work_dir and results_dir
    (a second one is refused: SweepLocked); one whose runs are all done only reads runs.csv, so it may
    summarise while another sweep runs. Ctrl-C (KeyboardInterrupt) stops the pool's workers with SIGTERM
    (each run saves a checkpoint), kills what is left after `stop_after` seconds, and raises again.
    keep_rows: count every row of runs.csv as done, produced here or not: to continue one's own sweep
    whose work folder is gone (another machine, a later sitting), never to reproduce one.
    """
    context = {} if context is None else context
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        raise ValueError(f"runs lists {sorted({i for i in ids if ids.count(i) > 1})} more than once")
    csv_path = os.path.join(results_dir, "runs.csv")
    done = done_rows(results_dir, work_dir, keep_rows)
    if all(i in done for i in ids):            # nothing to run: no lock (another sweep may be running)
        return _finished(done, ids)
    with contextlib.ExitStack() as stack:
        _lock(results_dir, ".sweep.lock", stack)
        _lock(work_dir, ".sweep.lock", stack)
        rows = read_rows(csv_path)
        done = done_rows(results_dir, work_dir, keep_rows)
        others = [row for row in rows if row_id(row) not in done]
        redo = sum(row_id(row) in ids for row in others)
        if redo:
            print(f"{csv_path}: {redo} rows of this sweep's runs were not produced by {work_dir} (committed "
                  f"results, or another machine's): they are run again here, and replaced as they finish",
                  file=sys.stderr)
        todo = [r for r in runs if r.run_id not in done]
        own = executor is None and bool(todo)
        if own:
            # spawn, not fork: a forked child would inherit the threads (tqdm's monitor, BLAS) mid-flight
            executor = concurrent.futures.ProcessPoolExecutor(
                workers, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_start,
                initargs=(os.getpid(),))
        bar = tqdm(total=len(runs), initial=len(runs) - len(todo), desc="runs", unit="run",
                   disable=not progress, file=sys.stderr)
        futures = {executor.submit(execute, run_fn, spec, os.path.abspath(os.path.join(work_dir, spec.run_id)),
                                   context): spec for spec in todo}
        try:
            for future in concurrent.futures.as_completed(futures):
                spec = futures[future]
                try:
                    row = future.result()
                except Exception as e:
                    first_line = (str(e).strip().splitlines() or [""])[0]
                    tqdm.write(f"run {spec.run_id} failed: {type(e).__name__}: {first_line} (traceback: "
                               f"{os.path.join(work_dir, spec.run_id, 'error.txt')}); run the sweep again to retry it",
                               file=sys.stderr)
                    continue
                done[spec.run_id] = row
                others = [r for r in others if row_id(r) != spec.run_id]
                write_rows(others + list(done.values()), csv_path)
                bar.set_postfix_str(spec.run_id, refresh=False)
                bar.update(1)
        except BaseException:                  # Ctrl-C: stop the runs (they checkpoint); runs.csv is whole
            if own:
                _stop(executor, stop_after)
            else:
                for future in futures:
                    future.cancel()
            raise
        finally:
            bar.close()
        if own:
            executor.shutdown()
    return _finished(done, ids)


def _stop(executor, grace):
    """Stop a process pool now: no new run starts, SIGTERM to its workers (a run saves its checkpoint and
    ends), SIGKILL to any left after `grace` seconds or at a second Ctrl-C."""
    processes = list(getattr(executor, "_processes", {}).values())   # the pool's worker processes
    executor.shutdown(wait=False, cancel_futures=True)               # no run starts from now on
    for p in processes:
        if p.is_alive():
            p.terminate()
    try:
        deadline = time.monotonic() + grace
        for p in processes:
            p.join(max(0.0, deadline - time.monotonic()))
    except KeyboardInterrupt:                  # a second Ctrl-C: no more waiting
        pass
    finally:
        for p in processes:
            if p.is_alive():
                p.kill()


def _finished(done, ids):
    """The rows of `done` ({run id: row}) whose ids are in `ids`, in runs.csv's order."""
    return sorted((done[i] for i in ids if i in done), key=row_order)
