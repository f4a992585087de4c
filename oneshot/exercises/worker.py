"""The sandbox's side of grading: two processes per submission, started by `grading.run_sandbox` as

    python -I -c "<boot>" JOB ROOT        (-I: no PYTHONPATH, no user site, no current folder on sys.path)

1. The supervisor (this module's `main`) runs no student code. It ends with the grader (prctl
   PR_SET_PDEATHSIG), imports the checkers, makes the exercises' cases, says "ready" on the channel
   (its stdout: a pipe only the grader reads), and forks the worker. It is a subreaper: whatever the
   worker forks, in whatever session, is its descendant, and `confine.kill_descendants` ends it all
   when the worker ends, when the grader sends SIGTERM (its timeout) or when the grader dies.
   Its exit status is the worker's (128 + N: killed by signal N).
2. The worker confines itself (`confine`: limits, Landlock, user nobody when root), arms the tripwires
   on the package's answers (`poison`), moves to the working copy, loads the submission, and for each
   exercise sends the OUTCOMES of the student's function on the cases (values, `wire`), never a verdict.
   Its sys.stdout and sys.stderr go to a log the grader reads only for a crash's last line, kept to
   its newest megabyte (`log_stream`): print() never fails for lack of room.
"""
import importlib.util
import io
import json
import os
import shutil
import signal
import sys
import traceback
import warnings

import numpy as np

from oneshot import exercises
from oneshot.exercises import CHECKERS, EXERCISES, SOLUTIONS, checking, confine, poison, wire
from oneshot.tools.host import die_with_parent

BOOT = ("import sys; sys.path.insert(0, sys.argv[2]); sys.dont_write_bytecode = True; "
        "from oneshot.exercises.worker import main; main(sys.argv[1])")
_worker = {"pid": None, "workdir": None}
_NAMES = {exercise.name for exercise in EXERCISES.values()}
LOG_BYTES = 1 << 20           # the log keeps at most this much of a submission's output: its newest


class _Log(io.RawIOBase):
    """The bytes the worker writes to the log (`fd`, opened for reading and writing), which keeps only
    its newest half when it would grow past `limit` bytes. So a submission that prints without end
    never reaches the file-size limit (`confine.limit`: print() would raise OSError inside the student's
    function), and the log's end, where the grader reads a crash's last line, is the newest output,
    after at least limit / 2 bytes of what came before it. `log_stream` makes it sys.stdout and
    sys.stderr."""

    def __init__(self, fd, limit):
        super().__init__()
        self.fd, self.limit = fd, limit

    def writable(self):
        return True

    def fileno(self):
        return self.fd

    def write(self, data):
        data = bytes(data)
        kept, end = data[-self.limit:], os.lseek(self.fd, 0, os.SEEK_CUR)
        if end + len(kept) > self.limit:
            half = self.limit // 2
            before = os.pread(self.fd, half, max(0, end - half))[max(0, len(kept) - half):]
            os.ftruncate(self.fd, 0)
            os.lseek(self.fd, 0, os.SEEK_SET)
            self._write_all(before)
        self._write_all(kept)
        return len(data)

    def _write_all(self, data):
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view):]


def log_stream(fd, limit=LOG_BYTES):
    """A text stream like Python's own sys.stdout (encoding, buffer, fileno, reconfigure), buffered, over
    a `_Log` of `fd`: what the worker's print() writes to."""
    return io.TextIOWrapper(io.BufferedWriter(_Log(fd, limit), 1 << 16), encoding="utf-8", errors="backslashreplace")


def _end(signum=None, frame=None):
    """The supervisor's last act when told to end (or when the grader died): kill the worker and
    everything it started, remove the working copy (the grader may not be there to), exit."""
    if _worker["pid"]:
        try:
            os.kill(_worker["pid"], signal.SIGKILL)
        except ProcessLookupError:
            pass
    confine.kill_descendants()
    if _worker["workdir"]:
        shutil.rmtree(_worker["workdir"], ignore_errors=True)
    os._exit(128 + (signum or signal.SIGTERM))


def main(text):
    """The supervisor. JOB (JSON, from the grader): submission, workdir, numbers, memory, cpu,
    processes, readable, hidden, parent (the grader's pid)."""
    job = json.loads(text)
    _worker["workdir"] = job["workdir"]
    channel = os.dup(1)
    os.dup2(2, 1)                                    # print() goes to the log, never into the channel
    signal.signal(signal.SIGTERM, _end)
    die_with_parent(job["parent"], signal.SIGTERM)
    confine.become_subreaper()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        cases = {n: CHECKERS[n].cases() for n in job["numbers"]}
    wire.send(channel, {"event": "ready"})
    pid = os.fork()
    if pid == 0:
        status = 1
        try:
            status = _work(job, channel, cases, os.getppid())
        except BaseException:                            # its last line is what the grader shows
            traceback.print_exc()
        finally:
            for stream in (sys.stdout, sys.stderr):      # buffered (`log_stream`): what it holds, to the log
                try:
                    stream.flush()
                except BaseException:
                    pass
            os._exit(status)
    _worker["pid"] = pid
    os.close(channel)
    _, status = os.waitpid(pid, 0)
    _worker["pid"] = None
    confine.kill_descendants()
    code = os.waitstatus_to_exitcode(status)
    os._exit(code if code >= 0 else 128 - code)


def _work(job, channel, cases, supervisor):
    """The worker: confine, arm, load, run. Returns the exit status."""
    die_with_parent(supervisor)
    os.chdir(job["workdir"])
    confine.limit(job["memory"], job["cpu"], job["processes"], uid=confine.NOBODY if os.geteuid() == 0 else None)
    poison.arm(exercises.ANSWERS, boundary=checking.attempt.__code__)
    exercises.check = lambda *args, **kwargs: None       # a notebook's check(5, ...) cells: grading is elsewhere
    confined = confine.landlock([job["workdir"]], job["readable"], job["hidden"])
    confine.drop_privileges(keep_files=bool(confined))
    os.closerange(3, channel)
    os.closerange(channel + 1, 1 << 16)
    sys.stdin = open(os.devnull)
    sys.stdout = sys.stderr = log_stream(2)
    try:
        functions, notes = _load(job)
    except _LoadError as e:
        wire.send(channel, {"event": "load-error", "message": str(e)})
        return 0
    wire.send(channel, {"event": "loaded", "notes": notes})
    for n in job["numbers"]:
        function = functions.get(EXERCISES[n].name)
        if function is None:
            wire.send(channel, {"event": "result", "exercise": n, "missing": True})
            continue
        room = wire.MAX_FRAME // (len(cases[n]) + 1)       # bytes each case's answer may take in the frame
        try:
            outcomes = [_outcome(EXERCISES[n], case, poison.submission(function), room) for case in cases[n]]
        except poison.PackageUsed as e:                   # outside `attempt`: the submission patched the checker
            outcomes = [{"used": e.package_function}] * len(cases[n])
        wire.send(channel, {"event": "result", "exercise": n, "outcomes": outcomes})
    return 0                                             # `main` flushes the log before the exit


def _outcome(exercise, case, function, room):
    """One case's Outcome, as wire data; a tripwire the function hit counts even if it caught PackageUsed."""
    poison.tripped.clear()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        outcome = checking.attempt(exercise, case, function)
    used = outcome.used or (poison.tripped[0] if poison.tripped else None)
    if used:
        return {"used": used}
    if outcome.not_written:
        return {"not_written": True}
    if outcome.error is not None:
        return {"error": outcome.error}
    try:
        value = wire.encode(outcome.value)
        if len(json.dumps(value)) > room:
            value = {"object": f"a result of more than {room >> 20} MB"}
    except BaseException:                                # a value whose own code raises while it is read
        value = {"object": "a value the checker cannot read"}
    return {"value": value, "changed": outcome.changed}


def _load(job):
    """The submission's functions (name -> callable), the first file in order that defines a name
    winning, and notes on the notebook cells that failed (`submissions.notebook_code`). A .py file that
    raises as it loads, after defining some of the exercises' functions, is graded on those, with a note,
    as a notebook whose later cell raises is; one that defined none, or cannot be parsed, is a load error."""
    sys.path.insert(0, job["workdir"])                   # a folder's files may import each other
    functions, notes = {}, []
    for index, file in enumerate(job["files"]):
        stem = "".join(c if c.isalnum() else "_" for c in os.path.basename(file)[:-3])
        spec = importlib.util.spec_from_file_location(f"_submission_{index}_{stem}", file)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException as e:                       # SyntaxError, any exception, sys.exit(), PackageUsed
            name = os.path.basename(file)
            name = name[:-3] if name.endswith(".ipynb.py") else name
            defined = [n for n, value in vars(module).items() if n in _NAMES and callable(value)]
            if isinstance(e, poison.PackageUsed) or not defined:     # a parse error defines nothing
                raise _LoadError(name, e) from None
            notes.append(f"{name} raised {checking.error_words(e)} as it loaded, after defining {', '.join(defined)}")
        for name, value in list(vars(module).items()):
            if not name.startswith("_") and callable(value):
                functions.setdefault(name, value)
        errors = vars(module).get("__notebook_errors__")
        if isinstance(errors, list):
            notes += [f"cell {n} raised {checking.error_words(e)}" for n, e in errors[:20]
                      if isinstance(e, BaseException)]
    return functions, notes


class _LoadError(Exception):
    """A .py file of the submission that failed as it loaded: "could not load bob.py: SyntaxError: ..."."""

    def __init__(self, file, error):
        super().__init__(f"could not load {file}: {checking.error_words(error)}")

