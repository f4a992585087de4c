"""The sandbox, from the grader's side: `run_sandbox` copies a submission into a fresh folder, starts
`oneshot.exercises.worker` there (a supervisor, in a session of its own, and the worker it forks),
reads the messages it sends within their deadlines, and ends it, with everything it started.

    python -I -c <worker.BOOT> JOB ROOT
        -I            no PYTHONPATH, user site or current folder on sys.path: a submission's numpy.py
                      cannot stand in for NumPy; ROOT, the folder holding this oneshot, comes first
        environment   only PATH, HOME and TMPDIR (the working copy), LANG, one BLAS thread: none of the
                      teacher's variables (tokens, keys) reach the submission
        JOB           the files to load, the exercises, the limits (`Limits`), the folders it may read
                      (Python, its libraries, the system) and may not (the package's source with the
                      reference solutions, the other submissions)
"""
import json
import os
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

import oneshot
from oneshot.exercises import confine, wire, worker
from oneshot.exercises.submissions import working_copy

STARTUP = 60.0                    # seconds for the sandbox's own imports, before the student's code runs
PACKAGE = os.path.dirname(os.path.realpath(oneshot.__file__))
READABLE = ("/usr", "/lib", "/lib64", "/lib32", "/bin", "/sbin", "/etc", "/dev", "/sys", "/proc/self")
stopping = threading.Event()      # set: every sandbox being read is ended within half a second (Ctrl-C)


@dataclass(frozen=True)
class Limits:
    """What one submission may use: `timeout` seconds per exercise (wall clock; its CPU time is limited
    to the same per exercise), `memory_mb` of memory beyond the checker's own, `processes` processes."""
    timeout: float = 10.0
    memory_mb: int = 1000
    processes: int = 16


def sandbox_gaps():
    """What this system cannot confine (words for a warning), e.g. on a kernel without Landlock."""
    abi, root = confine.landlock_abi(), os.geteuid() == 0
    who, whose = ("user nobody", "nobody's") if root else ("you", "your")
    gaps = [] if abi else [f"no Landlock on this kernel: submissions can read and write whatever {who} can, "
                           f"and use the network"]
    gaps += [f"Landlock ABI {abi} (Linux < 6.7): submissions can use TCP"] if 0 < abi < 4 else []
    gaps += [f"Landlock ABI {abi} (Linux < 6.12): submissions can signal {whose} processes"] if 0 < abi < 6 else []
    return gaps


def _environment(workdir):
    return {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": workdir, "TMPDIR": workdir,
            "LANG": "C.UTF-8", "MPLBACKEND": "Agg", "MPLCONFIGDIR": workdir,
            "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _readable():
    return list(READABLE) + _essential() + [p for p in sys.path if p and os.path.isdir(p)]


def _essential():
    return [sys.prefix, sys.base_prefix, sys.exec_prefix, os.path.dirname(os.__file__)]


def _hidden(paths):
    """The folders the sandbox may not read: the package's source, and `paths` (the submissions' folder),
    unless one holds Python itself (grading from /, say)."""
    essential = [os.path.join(os.path.realpath(p), "") for p in _essential()]
    paths = [os.path.join(os.path.realpath(p), "") for p in paths]
    return [PACKAGE] + [p.rstrip(os.sep) or os.sep for p in paths if not any(e.startswith(p) for e in essential)]


def run_sandbox(path, numbers, limits, valid, hidden=()):
    """Run submission `path` on exercises `numbers` in a sandbox. -> (messages, ending, why): the messages
    it sent, each checked by `valid(message, what is due)` (which raises wire.WireError), and how it ended: "done", "timeout", "channel" (it sent what the sandbox does
    not) or "crash", with why in words (the exit status and the last line of its output)."""
    workdir = tempfile.mkdtemp(prefix="oneshot-grade-")
    try:
        files = working_copy(path, workdir)
        job = {"files": files, "workdir": workdir, "numbers": list(numbers), "parent": os.getpid(),
               "memory": limits.memory_mb << 20, "cpu": limits.timeout * (1 + len(numbers)) + 2,
               "processes": limits.processes, "readable": _readable(),
               "hidden": _hidden(hidden)}
        with tempfile.TemporaryFile() as log:
            process = subprocess.Popen(
                [sys.executable, "-I", "-c", worker.BOOT, json.dumps(job), os.path.dirname(PACKAGE)],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log, cwd=workdir,
                env=_environment(workdir), start_new_session=True)
            try:
                messages, ending = _receive(process, list(numbers), limits.timeout, valid)
            finally:
                _end(process)
            log.seek(max(0, os.fstat(log.fileno()).st_size - 4096))
            tail = [line for line in log.read().decode(errors="replace").splitlines() if line.strip()]
    finally:
        shutil.rmtree(workdir, onerror=_force)
    code = process.returncode
    status = f"killed by {_signal_name(code - 128)}" if code > 128 else f"exit status {code}"
    return messages, ending, status + (f": {wire.clean(tail[-1], 200)}" if tail else "")


def _signal_name(number):
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def _force(function, path, error):
    """rmtree's error handler: a folder the submission made unreadable is made writable and removed."""
    try:
        os.chmod(os.path.dirname(path), 0o700)
        os.chmod(path, 0o700)
        shutil.rmtree(path, ignore_errors=True) if os.path.isdir(path) else os.unlink(path)
    except OSError:
        pass


def _end(process):
    """End a sandbox: its supervisor ends the worker and everything it started (SIGTERM); SIGKILL to its
    process group if it has not ended 5 s later."""
    if process.poll() is None:
        try:
            process.wait(0.5)                          # it may be ending on its own
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGTERM)
    try:
        process.wait(5)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait()
    process.stdout.close()


def _receive(process, numbers, timeout, valid):
    """Read the sandbox's messages: "ready" within STARTUP s, then "loaded" (or "load-error") and each
    exercise's "result", in order, within `timeout` s each. -> (messages, ending)."""
    expected = ["ready", "loaded"] + numbers
    messages, frames = [], wire.Frames()
    deadline = time.monotonic() + STARTUP
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        while expected:
            left = deadline - time.monotonic()
            if left <= 0:
                return messages, "timeout"
            if stopping.is_set():
                return messages, "stopped"
            if not selector.select(min(left, 0.5)):
                continue
            chunk = os.read(process.stdout.fileno(), 1 << 16)
            if not chunk:
                return messages, "crash"
            try:
                for message in frames.feed(chunk):
                    message = valid(message, expected[0])
                    messages.append(message)
                    if message["event"] == "load-error":
                        return messages, "done"
                    expected.pop(0)
                    deadline = time.monotonic() + timeout
            except wire.WireError:
                return messages, "channel"
    return messages, "done"
