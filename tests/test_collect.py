"""Collecting a dataset from the command line: the file is the content (the same bytes whatever the
worker count or the hour), a horizon too short for the expert is a named one-line error, and Ctrl-C
stops every process and writes nothing."""
import dataclasses
import glob
import os
import pathlib
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from oneshot.data import collection, datasets
from oneshot.training import config, run_data
from oneshot.world.reach import WorldConfig

ROOT = pathlib.Path(__file__).resolve().parents[1]
TINY_WORLD = WorldConfig(image_size=8, horizon=8)      # 8 steps: the expert reaches every scene


def python_m_collect(*argv, **kwargs):
    """Popen `python -m oneshot.collect argv` with Ctrl-C delivered as KeyboardInterrupt (a shell that
    started pytest in the background may have left SIGINT ignored, and the child would inherit that)."""
    return subprocess.Popen([sys.executable, "-m", "oneshot.collect", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), **kwargs)


def test_the_same_data_is_the_same_file_whatever_the_workers_and_the_hour(tmp_path):
    start = time.monotonic()
    one = collection.collect(2, 2, "train", seed=3, workers=1, world_cfg=TINY_WORLD, progress=False)
    datasets.save(one, tmp_path / "one.npz")
    two = collection.collect(2, 2, "train", seed=3, workers=2, world_cfg=TINY_WORLD, progress=False)
    time.sleep(max(0.0, 2.1 - (time.monotonic() - start)))   # zip dates count in 2 s steps: a later one
    datasets.save(two, tmp_path / "two.npz")
    datasets.save(one, tmp_path / "again.npz")
    first = (tmp_path / "one.npz").read_bytes()
    assert (tmp_path / "two.npz").read_bytes() == first and (tmp_path / "again.npz").read_bytes() == first
    assert not {"seconds", "workers"} & set(one["metadata"])
    with np.load(tmp_path / "one.npz") as f:                  # plain numpy reads it, e.g. in a notebook
        assert sorted(f.files) == sorted([*datasets.ARRAYS, "metadata"])
        assert np.array_equal(f["images"], one["images"])
    other = collection.collect(2, 2, "train", seed=4, workers=1, world_cfg=TINY_WORLD, progress=False)
    datasets.save(other, tmp_path / "other.npz")
    assert (tmp_path / "other.npz").read_bytes() != first


def test_a_horizon_too_short_for_the_expert_is_a_named_error(tmp_path):
    # In 5 steps the expert reaches about a third of the scenes (8 steps: all of them); with seed 0,
    # a demo of task 1 fails all MAX_ATTEMPTS scenes. Through the process pool as well as in-process:
    with pytest.raises(collection.ExpertFailed, match=r"failed 10 scenes in a row for task 1 .* in 5 steps "
                                                   r"it cannot reach .* use a longer --horizon \(the default is 20\)"):
        collection.collect(2, 2, "train", seed=0, workers=2, world_cfg=WorldConfig(image_size=8, horizon=5),
                        progress=False)
    out = tmp_path / "d.npz"
    process = python_m_collect("--out", str(out), "--tasks", "2", "--demos", "2", "--seed", "0", "--workers", "1",
                               "--image-size", "8", "--horizon", "5", "--noise", "0.1", cwd=tmp_path)
    _, err = process.communicate(timeout=120)
    shown = err.decode().split("\r")[-1]                      # what the terminal shows once tqdm's bar is wiped
    assert process.returncode == 2, err
    assert err.decode().count("\n") == 1 and shown.startswith("error: the expert failed 10 scenes"), err
    assert shown.rstrip().endswith("use a longer --horizon (the default is 20) or a smaller --noise"), err
    assert list(tmp_path.iterdir()) == []


def children(pid):
    """The pids of the processes `pid` started (Linux /proc)."""
    return {int(c) for f in glob.glob(f"/proc/{pid}/task/*/children") for c in pathlib.Path(f).read_text().split()}


def orphans_of(pid):
    """Processes whose parent is `pid`, found by their status files (after `pid` is gone)."""
    found = []
    for status in glob.glob("/proc/[0-9]*/status"):
        try:
            lines = pathlib.Path(status).read_text().splitlines()
        except OSError:                                       # it ended while we looked
            continue
        if f"PPid:\t{pid}" in lines:
            found.append(status)
    return found


def test_ctrl_c_stops_every_worker_says_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "d.npz"
    # 288 demos: several seconds for 2 workers. start_new_session: the signal goes to the process group,
    # as a terminal's Ctrl-C does, so the workers receive it too (and must ignore it).
    process = python_m_collect("--out", str(out), "--tasks", "36", "--demos", "8", "--workers", "2",
                               "--image-size", "8", cwd=tmp_path, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while len(children(process.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = children(process.pid)
        assert len(workers) == 2
        time.sleep(1.0)                                       # the workers are recording demos
        assert process.poll() is None, "the collection ended before it could be interrupted"
        os.killpg(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    err = err.decode()
    assert process.returncode == 130, err
    assert err.count("\n") == 1, err                         # the bar is wiped: one line
    assert re.fullmatch(r"error: interrupted while collecting train demos \(\d+ of 288 recorded\); "
                        + re.escape(str(out)) + r" was not written: run the same command again\n", err.split("\r")[-1]), err
    assert "Traceback" not in err
    assert [w for w in workers if os.path.exists(f"/proc/{w}")] == [] and orphans_of(process.pid) == []
    assert list(tmp_path.iterdir()) == []                     # no dataset, no .tmp-* file



def test_ctrl_c_while_train_collects_a_missing_dataset_names_the_file_not_written(tmp_path, monkeypatch):
    """`train` collects a missing dataset before its first iteration: Ctrl-C then says how far the
    collection got, which file was not written, and to run the same command again (no run exists yet
    to --resume)."""
    def interrupted(*args, **kwargs):
        raise collection.Interrupted("interrupted while collecting train demos (3 of 864 recorded)")
    monkeypatch.setattr(collection, "collect", interrupted)
    cfg = dataclasses.replace(config.PROFILES["smoke"], train_data=str(tmp_path / "t.npz"),
                              validation_data=str(tmp_path / "v.npz"))
    with pytest.raises(collection.Interrupted) as e:
        run_data.ensure(cfg, progress=False)
    assert str(e.value) == (f"interrupted while collecting train demos (3 of 864 recorded); {tmp_path / 't.npz'} "
                            f"was not written: run the same command again")
    assert list(tmp_path.iterdir()) == []
