"""A sweep of independent runs through any `concurrent.futures.Executor`, resumable, with one CSV row
per finished run, a summary over seeds and a figure (the machinery of `oneshot.experiments.fig2`).

    rows = sweep(runs, "results/", "work/", context, executor=None, run_fn=run_one)

Each run is `run_fn(spec, run_dir, context) -> {"successes", "trials", ...}`, called in a worker of the
executor (a process pool by default; a thread pool; Dask's `Client.get_executor()`): a module-level
function, since it is pickled, that writes only inside its own `run_dir`, where it keeps whatever it
needs to resume. results/runs.csv is rewritten atomically after every finished run; runs that already
have a row are skipped, so running the same sweep again resumes it.
"""
import concurrent.futures
import csv
import fcntl
import io
import json
import multiprocessing
import os
import sys
import time
import traceback
from dataclasses import dataclass

from tqdm import tqdm

from oneshot.tools.files import atomic_write, open_read, open_write
from oneshot.training.scoring import wilson_interval

try:
    from matplotlib.figure import Figure       # pip install ".[plots]": the figure (no pyplot, no global state)
except ImportError:
    Figure = None
PLOTS = Figure is not None                     # can `plot` draw here?


# runs.csv, in this column order. `notes`: whatever else run_fn returned, as compact JSON.
COLUMNS = ("method", "size", "colours", "demos_per_colour", "seed", "iterations", "wall_seconds",
           "successes", "trials", "rate", "ci_low", "ci_high", "notes")
_INT_COLUMNS = ("size", "colours", "demos_per_colour", "seed", "iterations", "successes", "trials")
_FLOAT_COLUMNS = ("wall_seconds", "rate", "ci_low", "ci_high")



@dataclass(frozen=True)
class RunSpec:
    """One run: `method` meta-trained for `iterations` meta-iterations on `colours` training colours x
    `demos` demos per colour, with seed `seed`."""
    method: str
    colours: int
    demos: int
    seed: int
    iterations: int

    def __post_init__(self):
        for name in ("colours", "demos"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"{name} must be an int >= 1; got {getattr(self, name)!r}")
        for name in ("seed", "iterations"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be an int >= 0; got {getattr(self, name)!r}")

    @property
    def size(self):
        """Meta-training demonstrations: colours x demos per colour."""
        return self.colours * self.demos

    @property
    def run_id(self):
        """A stable, filesystem-safe name, e.g. "lstm_c72_d12_s1_i6000": the run's work folder."""
        return f"{self.method}_c{self.colours}_d{self.demos}_s{self.seed}_i{self.iterations}"


# --- one run, in a worker ----------------------------------------------------------------------------

def row_of(spec, result, wall_seconds):
    """The runs.csv row (a dict over COLUMNS) of a finished run, from run_fn's result dict."""
    if not isinstance(result, dict) or "successes" not in result or "trials" not in result:
        raise ValueError(f"run_fn must return a dict with 'successes' and 'trials'; got {result!r}")
    successes, trials = int(result["successes"]), int(result["trials"])
    if not 0 <= successes <= trials or trials < 1:
        raise ValueError(f"run_fn returned {successes} successes in {trials} trials "
                         f"(need 0 <= successes <= trials, trials >= 1)")
    clash = sorted(set(result) & set(COLUMNS) - {"successes", "trials", "wall_seconds"})
    if clash:
        raise ValueError(f"run_fn returned {clash}: the sweep fills those columns itself")
    extra = {k: v for k, v in result.items() if k not in COLUMNS}
    lo, hi = wilson_interval(successes, trials)
    return {"method": spec.method, "size": spec.size, "colours": spec.colours, "demos_per_colour": spec.demos,
            "seed": spec.seed, "iterations": spec.iterations,
            "wall_seconds": round(float(result.get("wall_seconds", wall_seconds)), 2),
            "successes": successes, "trials": trials, "rate": round(successes / trials, 4),
            "ci_low": round(lo, 4), "ci_high": round(hi, 4),
            "notes": json.dumps(extra, sort_keys=True, separators=(",", ":"),
                                default=lambda x: x.item() if hasattr(x, "item") else str(x))}


def execute(run_fn, spec, run_dir, context):
    """Run `run_fn` on one spec (in a worker) and return its runs.csv row. On an error, the traceback
    is written to run_dir/error.txt and the error raised again."""
    os.makedirs(run_dir, exist_ok=True)
    error_file = os.path.join(run_dir, "error.txt")
    t0 = time.perf_counter()
    try:
        row = row_of(spec, run_fn(spec, run_dir, context), time.perf_counter() - t0)
    except BaseException:
        with open_write(error_file, "w") as f:
            f.write(traceback.format_exc())
        raise
    if os.path.exists(error_file):             # an earlier attempt failed; this one did not
        os.remove(error_file)
    return row


# --- runs.csv ------------------------------------------------------------------------------------------

def row_id(row):
    """The run_id of a runs.csv row."""
    return RunSpec(row["method"], row["colours"], row["demos_per_colour"], row["seed"], row["iterations"]).run_id


def read_rows(path):
    """The rows of a runs.csv (typed: ints, floats, notes as its JSON string); [] if there is none."""
    if not os.path.exists(path):
        return []
    with open_read(path, "r", newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise ValueError(f"{path}: columns {reader.fieldnames} are not runs.csv's {list(COLUMNS)}; "
                             f"move the file away to start the sweep afresh")
        rows = list(reader)
    for row in rows:
        row.update({k: int(row[k]) for k in _INT_COLUMNS})
        row.update({k: float(row[k]) for k in _FLOAT_COLUMNS})
    return rows


def row_order(row):
    """The order of runs.csv: (method, size, seed)."""
    return row["method"], row["size"], row["seed"], row["iterations"]


def write_rows(rows, path):
    """Write runs.csv atomically, sorted by (method, size, seed): never half a file at `path`."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(sorted(rows, key=row_order))
    with atomic_write(path) as f:
        f.write(text.getvalue().encode("utf-8"))


# --- the sweep -------------------------------------------------------------------------------------------

class SweepLocked(RuntimeError):
    """Another sweep is running in the same work folder."""


def sweep(runs, results_dir, work_dir, context, run_fn, executor=None, progress=True, workers=2):
    """Perform every run of `runs` (RunSpecs) not yet in results_dir/runs.csv; return the rows of the
    finished ones (dicts over COLUMNS, in runs.csv's order).

    Runs are submitted to `executor` (any concurrent.futures.Executor; default: a process pool of
    `workers` spawned processes, shut down at the end) as `run_fn(spec, work_dir/<run_id>, context)`
    Each finished run adds its row and runs.csv is rewritten atomically; a
    run that raises is named on stderr (traceback in its folder's error.txt) and left out, so the next
    sweep runs it again. Rows of runs not in `runs` are kept in the file but not returned. A sweep with
    runs to do holds a lock on work_dir (a second one is refused: SweepLocked); one whose runs have all
    finished only reads runs.csv, so it may summarise while another sweep runs.
    """
    context = {} if context is None else context
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        raise ValueError(f"runs lists {sorted({i for i in ids if ids.count(i) > 1})} more than once")
    csv_path = os.path.join(results_dir, "runs.csv")
    done = {row_id(row): row for row in read_rows(csv_path)}      # runs.csv is replaced whole: safe to read
    if all(i in done for i in ids):            # nothing to run: no lock (another sweep may be running)
        return _finished(done, ids)
    os.makedirs(work_dir, exist_ok=True)
    with open_write(os.path.join(work_dir, ".sweep.lock"), "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)   # released when the file closes
        except BlockingIOError:
            raise SweepLocked(f"another sweep is running in {work_dir} (it holds {lock.name})") from None
        done = {row_id(row): row for row in read_rows(csv_path)}
        foreign = len(set(done) - set(ids))
        if foreign:
            print(f"{csv_path}: keeping {foreign} rows of runs outside this sweep", file=sys.stderr)
        todo = [r for r in runs if r.run_id not in done]
        own = executor is None and bool(todo)
        if own:
            # spawn, not fork: a forked child would inherit the threads (tqdm's monitor, BLAS) mid-flight
            executor = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
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
                write_rows(list(done.values()), csv_path)
                bar.set_postfix_str(spec.run_id, refresh=False)
                bar.update(1)
        except BaseException:                  # Ctrl-C: drop the runs not started; runs.csv is whole
            for future in futures:
                future.cancel()
            if own:
                executor.shutdown(wait=False, cancel_futures=True)
            raise
        finally:
            bar.close()
        if own:
            executor.shutdown()
    return _finished(done, ids)


def _finished(done, ids):
    """The rows of `done` ({run id: row}) whose ids are in `ids`, in runs.csv's order."""
    return sorted((done[i] for i in ids if i in done), key=row_order)
