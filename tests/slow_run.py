"""The run function a sweep's spawned workers execute in tests/test_sweep_faults.py, in a module of its
own: each worker imports it, and this module imports nothing of the package (a test module would make
every worker import the test suite's imports, about a second and a half each)."""
import os
import time


def slow_run(spec, run_dir, context):
    """A run that says its pid (in run_dir/pid) and then works for a minute, unless stopped."""
    with open(os.path.join(run_dir, "pid"), "w") as f:
        f.write(str(os.getpid()))
    time.sleep(60)
    return {"successes": 0, "trials": 1}
