"""A sweep's results and processes under faults and misuse (oneshot/experiments/sweep.py, rows.py):
rows it did not produce are never taken for done, two sweeps that share a results folder keep each
other's rows, a damaged runs.csv is named with its line, and the pool's processes end with the sweep
however it ends (kill -9, SIGTERM, Ctrl-C once or twice)."""
import concurrent.futures
import contextlib
import fcntl
import json
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from tqdm import tqdm

from oneshot.experiments import rows as sweep_rows
from oneshot.experiments import sweep as sweeping
from oneshot.experiments.rows import RunSpec
from oneshot.experiments.sweep import SweepLocked, sweep
from test_experiments import fake_run, without_time


def calls(run_dir):
    """How many times fake_run ran in this run's folder."""
    return len(list(run_dir.glob("call-*")))


RUNS = [RunSpec("mil-conv0", c, 3, s, 2) for c in (3, 4) for s in (0, 1)]
CONTEXT = {"trials": 2, "profile": "t"}


def threaded(runs, results_dir, work_dir, **kwargs):
    """`sweep` of fake_run in two threads: the rows' bookkeeping without the seconds a pool of spawned
    processes takes to start (the pool itself: test_the_pools_workers_end_with_the_sweep_however_it_ends)."""
    with concurrent.futures.ThreadPoolExecutor(2) as executor:
        return sweep(runs, results_dir, work_dir, CONTEXT, fake_run, executor=executor, progress=False, **kwargs)


def test_rows_the_work_folder_did_not_produce_are_run_again_and_replaced(tmp_path):
    """The committed results of a fresh clone (a runs.csv whose work folders are elsewhere) are not a
    reproduction: every run is done here, and each row replaced by this work folder's."""
    committed = threaded(RUNS, tmp_path / "theirs", tmp_path / "their_work")
    shutil.copytree(tmp_path / "theirs", tmp_path / "results")                   # what a clone holds
    mine = threaded(RUNS, tmp_path / "results", tmp_path / "my_work")
    assert all(calls(tmp_path / "my_work" / r.run_id) == 1 for r in RUNS)      # every run done here
    assert without_time(mine) == without_time(committed)                         # the same numbers, here
    again = threaded(RUNS, tmp_path / "results", tmp_path / "my_work")
    assert again == mine and all(calls(tmp_path / "my_work" / r.run_id) == 1 for r in RUNS)   # now done


def test_keep_rows_continues_ones_own_sweep_whose_work_folder_is_gone(tmp_path):
    done = [r for r in RUNS if r.seed == 0]
    threaded(done, tmp_path / "results", tmp_path / "lost_work")
    rows = threaded(RUNS, tmp_path / "results", tmp_path / "new_work", keep_rows=True)
    assert len(rows) == len(RUNS)
    assert [r.run_id for r in RUNS if calls(tmp_path / "new_work" / r.run_id)] == [r.run_id for r in RUNS if r.seed == 1]


def test_a_row_changed_by_hand_is_not_done(tmp_path):
    threaded(RUNS, tmp_path / "results", tmp_path / "work")
    csv = tmp_path / "results" / "runs.csv"
    rows = sweep_rows.read_rows(csv)
    rows[0]["successes"] = rows[0]["trials"]                                     # a better number, by hand
    sweep_rows.write_rows(rows, csv)
    threaded(RUNS, tmp_path / "results", tmp_path / "work")
    assert sorted(calls(tmp_path / "work" / r.run_id) for r in RUNS) == [1, 1, 1, 2]


def test_two_sweeps_sharing_a_results_folder_keep_each_others_rows(tmp_path):
    first = [r for r in RUNS if r.seed == 0]
    second = [r for r in RUNS if r.seed == 1]
    threaded(first, tmp_path / "out", tmp_path / "work0")
    threaded(second, tmp_path / "out", tmp_path / "work1")
    assert len(sweep_rows.read_rows(tmp_path / "out" / "runs.csv")) == len(RUNS)
    # while one sweep writes to the results folder, another is refused at once
    (tmp_path / "out" / "runs.csv").unlink()
    with open(tmp_path / "out" / ".sweep.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        with pytest.raises(SweepLocked, match="another sweep is running with"):
            threaded(second, tmp_path / "out", tmp_path / "work2")
    assert not (tmp_path / "work2").exists() or not any((tmp_path / "work2").iterdir())


GOOD = "mil-conv0,9,3,3,0,2,1.0,1,4,0.25,0.05,0.7,{}"


@pytest.mark.parametrize("text, says", [
    ("method,size\n" + GOOD + "\n", "columns"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD + "\n" + GOOD[:30] + "\n",
     r"line 3: not a runs.csv row \(it has 10 fields, not 13\)"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD + ",x,y\n", r"line 2: not a runs.csv row \(it has 15 fields, not 13\)"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace(",1,4,", ",5,4,") + "\n", "line 2: .*5 successes in 4 trials"),
    (",".join(sweep_rows.COLUMNS) + "\nhello,world\n", "line 2: not a runs.csv row"),
    (",".join(sweep_rows.COLUMNS) + '\n' + GOOD.replace("{}", '"{""per_colour"":{""1"":')[:-1] + "\n", "line 2"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace(",2,1.0,", ",two,1.0,") + "\n", "line 2"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace(",1,4,", ",-1,4,") + "\n", "line 2: .*-1 successes in 4 trials"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace(",1,4,", ",0,0,") + "\n", "line 2: .*0 successes in 0 trials"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("{}", "[]") + "\n", "line 2: .*its notes are not a JSON object"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("mil-conv0,9,3,3,0,", "mil-conv0,9,3,3,-10,") + "\n",
     r"line 2: not a runs.csv row \(3 colours x 3 demos, seed -10, 2 iterations\)"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("mil-conv0,9,3,3,", "mil-conv0,0,0,3,") + "\n",
     r"line 2: not a runs.csv row \(0 colours x 3 demos"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("mil-conv0,9,3,3,", "mil-conv0,12,3,3,") + "\n",
     r"line 2: not a runs.csv row \(size 12 is not 3 colours x 3 demos\)"),
    # notes' per_colour, which `difference` and the figure's intervals pair over colours
    *((",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("{}", '"{""per_colour"": ' + counts + '}"') + "\n",
       r"line 2: not a runs.csv row \(its notes' per_colour " + says) for counts, says in (
        ('{""0"": 999, ""1"": -998}', r"\(2 colours, 1 successes: 999 on colour 0, -998 on colour 1\) does not fit "
                                     r"its 1 successes in 4 trials, 2 a colour"),
        ('{""0"": 1, ""1"": 1}', r"\(2 colours, 2 successes\) does not fit its 1 successes"),
        ('{""0"": 1, ""1"": 0, ""2"": 0}', r"\(3 colours, 1 successes\) does not fit its 1 successes in 4 trials, "
                                          r"1.33333 a colour"),
        ('{""0"": ""x"", ""1"": 0}', "is not {colour: successes}, whole numbers"),
        ('{""0"": 1.0, ""1"": 0}', "is not {colour: successes}, whole numbers"),
        ('{""a"": 1, ""1"": 0}', "is not {colour: successes}, whole numbers"),
        ('{""00"": 1, ""1"": 0}', "is not {colour: successes}, whole numbers"),        # "0" twice, as int() reads it
        ('{""\u00b2"": 1, ""1"": 0}', "is not {colour: successes}, whole numbers"),     # a digit int() refuses
        ('{}', "is not {colour: successes}, whole numbers"),
        ('[1, 0]', "is not {colour: successes}, whole numbers"))),
    ("", r"runs.csv is empty \(not even runs.csv's header\); delete it to start the sweep afresh"),
    ("\r\n", r"runs.csv is empty \(not even runs.csv's header\)"),
    # a quote that runs on: the row begins where it opens; deleting that line keeps the good rows it swallowed
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD + '\ngarbage,,,"unterminated\n' + GOOD + "\n" + GOOD + "\n",
     r"lines 3-5 \(one row: a quote opened on line 3 runs on\): not a runs.csv row .*; delete line 3 \(its run"),
    ("\r\n".join([",".join(sweep_rows.COLUMNS), GOOD, 'garbage,,,"unterminated', GOOD, ""]),      # Windows line ends
     r"lines 3-4 \(one row: a quote opened on line 3 runs on\)"),
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD + '\ngarbage,,,"' + "x" * 200000 + "\n",            # past csv's field limit
     r"runs.csv, from line 3: not a runs.csv row \(field larger than field limit .*delete line 3"),
    (",".join(sweep_rows.COLUMNS) + "\n\n" + GOOD[:30] + "\n", r"runs.csv, line 3: not a runs.csv row"),  # an empty line
    (",".join(sweep_rows.COLUMNS) + "\n" + GOOD + "\n   \n", r"runs.csv, line 3: not a runs.csv row \(it has 1 fields"),
])
def test_a_damaged_runs_csv_is_named_with_its_line(tmp_path, text, says):
    path = tmp_path / "runs.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=says):
        sweep_rows.read_rows(path)


def test_a_runs_csv_row_with_per_colour_counts_that_fit_is_read(tmp_path):
    path = tmp_path / "runs.csv"
    path.write_text(",".join(sweep_rows.COLUMNS) + "\n" + GOOD.replace("{}", '"{""per_colour"": {""0"": 1, ""1"": 0}}"')
                    + "\n")
    assert json.loads(sweep_rows.read_rows(path)[0]["notes"])["per_colour"] == {"0": 1, "1": 0}


@pytest.mark.parametrize("data", [b"\xa7\x00\xff binary", (",".join(sweep_rows.COLUMNS) + "\n").encode() + b"\xa7\xff\n"])
def test_a_runs_csv_that_is_not_text_is_named_with_the_fix(tmp_path, data):
    """It said "'utf-8' codec can't decode byte 0xa7 in position 0", naming neither the file nor a fix."""
    path = tmp_path / "runs.csv"
    path.write_bytes(data)
    with pytest.raises(ValueError, match=f"{path} is not a runs.csv \\(it is not text\\); move the file away"):
        sweep_rows.read_rows(path)


SWEEP_SCRIPT = """
import signal, sys, time
sys.path.insert(0, {tests!r})
def interrupt(signum, frame):                   # as the command does: a plain kill is Ctrl-C
    raise KeyboardInterrupt
signal.signal(signal.SIGTERM, interrupt)
from oneshot.experiments.rows import RunSpec
from oneshot.experiments.sweep import sweep
import slow_run
runs = [RunSpec("mil-conv0", 3, 3, s, 2) for s in range(4)]
try:
    sweep(runs, {out!r}, {work!r}, {{}}, slow_run.slow_run, progress=False, workers=2, stop_after=5.0)
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:                         # a zombie is dead
        return f.read().split(")")[-1].split()[0] != "Z"


def _start_sweep(tmp_path):
    script = SWEEP_SCRIPT.format(tests=os.path.dirname(os.path.abspath(__file__)), out=str(tmp_path / "out"),
                                 work=str(tmp_path / "work"))
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, pids = time.time() + 60, []
    while time.time() < deadline and len(pids) < 2:
        pids = [int(p.read_text()) for p in (tmp_path / "work").glob("*/pid") if p.read_text()]
        time.sleep(0.1)
    assert len(pids) == 2, "the sweep's two workers never started"
    return parent, pids


def _all_gone(pids, seconds):
    deadline = time.time() + seconds
    while time.time() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    return not any(_alive(p) for p in pids)


@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM", "SIGINT", "SIGINT twice"])
def test_the_pools_workers_end_with_the_sweep_however_it_ends(tmp_path, how):
    parent, pids = _start_sweep(tmp_path)
    try:
        for _ in range(2 if how.endswith("twice") else 1):
            parent.send_signal(getattr(signal, how.split()[0]))
            time.sleep(0.2)
        out, err = parent.communicate(timeout=20)               # the sweep itself ends, never hangs
        assert _all_gone(pids, 10), f"workers still alive after {how}"
        if how != "SIGKILL":                                     # one line, as for Ctrl-C; a second Ctrl-C
            assert "interrupted" in out and parent.returncode in (130, -signal.SIGINT), err   # may end it at once
            assert "Traceback" not in err and "Exception" not in err, err
    finally:
        with contextlib.suppress(ProcessLookupError):
            parent.kill()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _progress_bar_locks():
    """In a sweep's worker: the modules of the locks its progress bars take."""
    tqdm(disable=True).close()
    lock = tqdm.get_lock()                     # tqdm's own lock holds a list of locks; one set is one lock
    return [type(each).__module__ for each in getattr(lock, "locks", [lock])]


def test_a_sweep_workers_progress_bars_leave_no_named_semaphore_behind():
    """A worker killed at a second Ctrl-C runs no clean-up, so what it made must need none: tqdm's default
    lock is a named semaphore, which Python's resource tracker reports as leaked at the sweep's exit."""
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=context, initializer=sweeping._worker_start,
                                                initargs=(os.getpid(),)) as pool:
        locks = pool.submit(_progress_bar_locks).result(timeout=120)
    assert locks and not any(module.startswith("multiprocessing") for module in locks), locks
