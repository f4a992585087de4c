"""Loading a student's submission, and grading a folder of them.

A submission is a .py file, or a folder of .py files, named for the student; it defines the exercises'
functions by their names (`EXERCISES[n].name`). Student code is untrusted: it may loop forever, crash
Python or print anything. So `grade` checks each submission in its own Python process (this module's
`child`, run as `python -m oneshot.exercises _grade-child`), which reports one JSON line per exercise;
a process that stays silent for `timeout` seconds is killed (its whole process group), its exercise
is reported as timed out, and a new process checks the exercises left.
"""
import contextlib
import importlib.util
import itertools
import json
import os
import selectors
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from oneshot.exercises import EXERCISES, Result, check
from oneshot.exercises.checking import error_words

PROTOCOL = "@@oneshot-exercises "        # the child's report lines start with this; other output is ignored
_modules = itertools.count()


class SubmissionError(Exception):
    """A submission that cannot be used: missing, not Python, or failing as it loads."""


def python_files(path):
    """The .py files of a submission: the file itself, or a folder's .py files in name order."""
    path = Path(path)
    if path.is_file() and path.suffix == ".py":
        return [path]
    if path.is_dir() and sorted(path.glob("*.py")):
        return sorted(path.glob("*.py"))
    if not path.exists():
        raise SubmissionError(f"no such file or folder: {path}")
    raise SubmissionError(f"{path} is not a .py file or a folder of them")


def load_functions(path):
    """Name -> function for every function a submission defines (in a folder, the first file in name
    order that defines a name wins). Runs the student's code: raises SubmissionError if it fails."""
    functions = {}
    for file in python_files(path):
        module_name = f"_submission_{next(_modules)}_{file.stem}"
        spec = importlib.util.spec_from_file_location(module_name, file)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        sys.path.insert(0, str(file.parent.resolve()))      # a folder's files may import each other
        try:
            spec.loader.exec_module(module)
        except BaseException as e:                          # SyntaxError, any exception, sys.exit()
            raise SubmissionError(f"could not load {file.name}: {error_words(e)}") from None
        finally:
            sys.path.remove(str(file.parent.resolve()))
        for name, value in vars(module).items():
            if callable(value) and not name.startswith("_"):
                functions.setdefault(name, value)
    return functions


def judge(number, function):
    """`check` without printing, refusing the package's own function in place of the student's."""
    exercise = EXERCISES[number]
    origin = getattr(function, "__module__", None) or ""
    if origin == "oneshot" or origin.startswith("oneshot."):
        return Result(number, False, f"your {exercise.name} is {origin}.{getattr(function, '__name__', '?')}, "
                                     f"the package's own: write your own", exercise.title)
    return check(number, function, quiet=True)


# ----------------------------------------------------------------------------------------------------
# The child: check one submission, report line by line
# ----------------------------------------------------------------------------------------------------


def child(path, numbers):
    """Check `numbers` of the submission at `path`; report each result as a PROTOCOL line on stdout.
    The student's own output goes to stderr, so it cannot garble the reports."""
    channel = sys.stdout

    def send(**event):
        channel.write(PROTOCOL + json.dumps(event) + "\n")
        channel.flush()
    send(event="ready")
    with contextlib.redirect_stdout(sys.stderr):
        try:
            functions = load_functions(path)
        except SubmissionError as e:
            send(event="load-error", message=str(e))
            return
        send(event="loaded")
        for number in numbers:
            function = functions.get(EXERCISES[number].name)
            if function is None:
                send(event="result", exercise=number, status="missing", message="")
                continue
            try:
                result = judge(number, function)
            except BaseException as e:                      # sys.exit() or KeyboardInterrupt in their code
                result = Result(number, False, f"your {EXERCISES[number].name} stopped the checker: {error_words(e)}")
            send(event="result", exercise=number, status="correct" if result.passed else "not yet",
                 message="" if result.passed else result.message)


# ----------------------------------------------------------------------------------------------------
# The parent: run children with a timeout, grade a folder
# ----------------------------------------------------------------------------------------------------


def _run_child(path, numbers, timeout, startup=120.0):
    """Run a child on `numbers`; kill it when it is silent for `timeout` s (`startup` s before its first
    report, which comes once Python and the package are imported). -> (events, timed_out, why it died)."""
    command = [sys.executable, "-m", "oneshot.exercises", "_grade-child", str(path), ",".join(map(str, numbers))]
    events, buffer, timed_out = [], b"", False
    with tempfile.TemporaryFile() as stderr:
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr,
                                   start_new_session=True)     # its own process group: killed whole below
        deadline = time.monotonic() + max(startup, timeout)
        with selectors.DefaultSelector() as selector:
            selector.register(process.stdout, selectors.EVENT_READ)
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    timed_out = True
                    break
                if not selector.select(left):
                    continue
                chunk = os.read(process.stdout.fileno(), 1 << 16)
                if not chunk:
                    break                                      # the child has finished (or died)
                *lines, buffer = (buffer + chunk).split(b"\n")
                for line in lines:
                    text = line.decode(errors="replace")
                    if text.startswith(PROTOCOL):
                        with contextlib.suppress(ValueError):
                            events.append(json.loads(text[len(PROTOCOL):]))
                            deadline = time.monotonic() + timeout      # each step gets `timeout` seconds
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)           # the child and anything the student started
        process.wait()
        process.stdout.close()
        stderr.seek(0)
        tail = [line for line in stderr.read().decode(errors="replace").splitlines() if line.strip()]
    code = process.returncode
    why = (f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}") + \
        (f": {tail[-1][:200]}" if tail else "")
    return events, timed_out, why


def grade_submission(path, numbers, timeout=60.0):
    """-> (load_error or None, {number: "correct" | "missing" | "not yet: ..." | "timed out ..." | "crashed ..."})."""
    verdicts, pending = {}, list(numbers)
    while pending:
        events, timed_out, why = _run_child(path, pending, timeout)
        loaded = False
        for event in events:
            if event.get("event") == "load-error":
                return event.get("message", "could not load"), verdicts
            loaded = loaded or event.get("event") == "loaded"
            if event.get("event") == "result" and event.get("exercise") in pending:
                status, message = event.get("status"), event.get("message")
                verdicts[event["exercise"]] = f"{status}: {message}" if message else status
                pending.remove(event["exercise"])
        if not pending:
            break
        if not loaded:
            loading = f"timed out after {timeout:g} s while loading" if timed_out else f"crashed while loading ({why})"
            return loading, verdicts
        number = pending.pop(0)                              # the exercise the child was checking
        verdicts[number] = (f"timed out after {timeout:g} s (an endless loop?)" if timed_out
                            else f"crashed Python ({why})")
    return None, verdicts


def submissions(folder):
    """The submissions in a folder: its .py files and its folders holding .py files, in name order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SubmissionError(f"no such folder: {folder}")
    found = sorted(p for p in folder.iterdir() if not p.name.startswith((".", "_"))
                   and ((p.is_file() and p.suffix == ".py") or (p.is_dir() and any(p.glob("*.py")))))
    if not found:
        raise SubmissionError(f"{folder} holds no submissions (.py files, or folders of them)")
    return found


def grade(folder, timeout=60.0, jobs=None, out=print):
    """Grade every submission in `folder` against every exercise: one line per submission and exercise,
    and a total per submission, printed in name order as they finish. Returns {submission: verdicts}."""
    found, numbers = submissions(folder), sorted(EXERCISES)
    labels = [p.name + ("/" if p.is_dir() else "") for p in found]
    width = max(map(len, labels))
    graded = {}
    with ThreadPoolExecutor(jobs or os.cpu_count() or 1) as pool:
        results = pool.map(lambda p: grade_submission(p, numbers, timeout), found)
        for label, (load_error, verdicts) in zip(labels, results):
            if load_error:
                out(f"{label:<{width}}   -  {load_error}")
            for number in numbers if not load_error else []:
                out(f"{label:<{width}}  {number:>2}  {verdicts[number]}")
            correct = sum(v == "correct" for v in verdicts.values())
            attempted = sum(v != "missing" for v in verdicts.values())
            out(f"{label:<{width}}  total  {correct}/{len(numbers)} correct, {attempted} attempted")
            graded[label] = load_error or verdicts
    return graded
