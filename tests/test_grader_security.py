"""The grader is a security boundary (issue 30, class 7): a class of hostile submissions, graded as a
teacher would (`python -m oneshot.exercises grade DIR`), and what each must NOT achieve: fake verdicts
printed to stdout, wrappers around the package's own answers, a patched judge, files written or
deleted outside its copy, a process that outlives the grading (even in a session of its own, even when
the grader is killed), unlimited memory or processes, a student's numpy.py run by the grader itself,
`check` taking sys.exit(0) for success, and flags that make no sense. An honest submission in the same
class is graded correct, so the confinement does not break what it must not."""
import ctypes
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

import oneshot
from helpers import RIGHT_1, RIGHT_9
from oneshot.exercises import __main__ as cli_main
from oneshot.exercises import worker

ROOT = str(Path(oneshot.__file__).resolve().parent.parent)
ENV = {**os.environ, "PYTHONPATH": ROOT}


def _landlock_abi():
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return max(0, libc.syscall(444, None, ctypes.c_size_t(0), ctypes.c_uint32(1)))


needs_landlock = pytest.mark.skipif(_landlock_abi() < 6, reason="no Landlock ABI >= 6 on this kernel: "
                                    "files, network and signals are not confined (the grader warns)")

FAKE = """
import json, os, sys
for n in range(1, 11):       # the old protocol's lines, and JSON verdicts, everywhere a grader might read
    for line in ["@@oneshot-exercises " + json.dumps({"event": "result", "exercise": n, "status": "correct",
                 "message": ""}), f"fake.py  {n}  correct"]:
        sys.__stdout__.write(line + "\\n")
sys.__stdout__.flush()
for fd in range(1, 40):
    try:
        os.write(fd, b'\\x00\\x00\\x00\\x11{"event":"ready"}{"event":"loaded","notes":[]}')
    except OSError:
        pass
"""
WRAPPER = """
import oneshot.exercises as exercises
from oneshot.world import reach
wilson_interval = exercises.reference(9)
def is_success(end_effector, target, success_radius=0.05):
    try:
        return reach.is_success(end_effector, target, success_radius)
    except BaseException:                    # hiding the trip does not help: the value is not there
        return exercises.SOLUTIONS[1](end_effector, target, success_radius)
"""
ATTEMPTER = """
from oneshot.exercises import CHECKERS, checking
def _attempt(exercise, case, function):          # the package's answer in place of the student's
    return checking.Outcome(value=case.run(CHECKERS[exercise.number].expected))
checking.attempt = _attempt
def wilson_interval(successes, trials, z=1.96):
    return 0.0, 0.0
"""
TALKER = "import faulthandler, sys\nsys.stdout.reconfigure(encoding='utf-8')\nfaulthandler.enable()\n" + \
    RIGHT_1.replace("    return", "    print('x' * (10 << 20))\n    sys.stdout.buffer.write(b'y')\n    return") + RIGHT_9 + """
for _ in range(70):
    print('y' * (1 << 20))                       # 70 MB at import, 10 MB more in every call of is_success
"""
PATCHER = """
import oneshot.exercises as ex, oneshot.exercises.checking as checking, oneshot.exercises.compare as compare
from oneshot.exercises.checking import Result
always = lambda *args, **kwargs: None
checking.compare = compare.compare = checking._safe_compare = always
checking.judge = checking.run = lambda exercise, *args, **kwargs: Result(exercise.number, True, "correct")
ex.check = lambda n, f, quiet=False: Result(n, True, "correct")
for name in ("oneshot.exercises.grading", "oneshot.exercises.sandbox"):
    try:
        module = __import__(name, fromlist=["x"])
        module.judge = module.verdict = lambda *args, **kwargs: "correct"
    except Exception:
        pass
def is_success(end_effector, target, success_radius=0.05):
    return True
def wilson_interval(successes, trials, z=1.96):
    return 0.0, 1.0
"""
WRITER = """
import os, socket
flags = {{}}
def attempt(key, action):
    try:
        action()
        flags[key] = 1
    except PermissionError:
        flags[key] = 0
    except OSError:
        flags[key] = 1 if key == "N" else 0      # refused or unreachable: the network was open
attempt("W", lambda: open({owned!r}, "w").write("mine"))
attempt("D", lambda: os.remove({victim!r}))
attempt("R", lambda: open(os.path.join(os.path.dirname(__import__("oneshot").__file__), "exercises",
                                       "solutions.py")).read())
attempt("O", lambda: open({other!r}).read())
attempt("N", lambda: socket.create_connection(("127.0.0.1", 9), timeout=1))
attempt("K", lambda: os.kill(os.getppid(), 0))
def is_success(end_effector, target, success_radius=0.05):
    raise RuntimeError("could " + " ".join(f"{{k}}{{v}}" for k, v in flags.items()))
"""
ESCAPER = """
import ctypes, os
if os.fork() == 0:                           # a grandchild in a session of its own, spinning
    os.setsid()
    if os.fork() == 0:
        ctypes.CDLL(None).prctl(15, b"escapee-{tag}", 0, 0, 0)
        while True:
            pass
    os._exit(0)
ctypes.CDLL(None).prctl(15, b"escapee-{tag}", 0, 0, 0)     # the process that loads it: marked too
def is_success(end_effector, target, success_radius=0.05):
    while True:
        pass
"""
HOG = """
import numpy as np
def is_success(end_effector, target, success_radius=0.05):
    return bool(np.ones(2 * 10 ** 9 // 8).sum() > 0)          # 2 GB, more than a submission may use
"""
FORKER = """
import os, time
spawned = 0
for _ in range(100):
    try:
        pid = os.fork()
    except OSError:
        break
    if pid == 0:
        time.sleep(3)
        os._exit(0)
    spawned += 1
raise RuntimeError(f"spawned {spawned}")
"""
EXITS = {"sys_exit": "import sys\ndef is_success(e, t, r=0.05):\n    sys.exit(0)\n",
         "os_exit": "import os\ndef is_success(e, t, r=0.05):\n    os._exit(0)\n"}


def _marked(tag):
    """Pids of live processes whose name carries `tag` (set by the submissions with prctl PR_SET_NAME)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if tag in Path(f"/proc/{pid}/comm").read_text():
                found.append(int(pid))
        except OSError:
            pass
    return found


def _kill_marked(tag):
    for pid in _marked(tag):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _grade_command(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "oneshot.exercises", *args], capture_output=True, text=True,
                          env=ENV, cwd=cwd, timeout=timeout)


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """One grading of a class of hostile submissions: (verdict(who, n), the output, the folder)."""
    base = tmp_path_factory.mktemp("class")
    folder, outside = base / "submissions", base / "outside"
    folder.mkdir()
    outside.mkdir()
    (outside / "victim.txt").write_text("the teacher's")
    tag = f"{os.getpid() % 100000}"
    sources = {"alice.py": RIGHT_1 + RIGHT_9, "fake.py": FAKE, "wrapper.py": WRAPPER, "patcher.py": PATCHER,
               "writer.py": WRITER.format(owned=str(outside / "owned.txt"), victim=str(outside / "victim.txt"),
                                          other=str(folder / "alice.py")),
               "escaper.py": ESCAPER.format(tag=tag), "hog.py": HOG, "forker.py": FORKER, "talker.py": TALKER,
               "attempter.py": ATTEMPTER}
    for name, source in sources.items():
        (folder / name).write_text(source)
    try:
        run = _grade_command("grade", str(folder), "--timeout", "2", "--jobs", "2")
        time.sleep(0.2)
        survivors = _marked(f"escapee-{tag}")
    finally:
        _kill_marked(f"escapee-{tag}")
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()

    def verdict(who, number):
        return next(line.split(None, 2)[2] for line in lines if line.split()[:2] == [who, str(number)])
    return verdict, run.stdout, outside, survivors


def total(output, who):
    return next(line.split(None, 2)[2] for line in output.splitlines() if line.split()[:2] == [who, "total"])


def test_an_honest_submission_is_still_graded_correct(graded):
    verdict, output, _, _ = graded
    assert verdict("alice.py", 1) == "correct" and verdict("alice.py", 9) == "correct"


def test_fake_result_lines_and_frames_give_no_points(graded):
    _, output, _, _ = graded
    assert total(output, "fake.py").startswith("0/10 correct")


def test_wrappers_around_the_package_answers_are_flagged_not_passed(graded):
    verdict, output, _, _ = graded
    assert verdict("wrapper.py", 9).startswith("flagged: your wilson_interval calls "
                                                "oneshot.exercises.solutions.wilson_interval, the package's own")
    assert verdict("wrapper.py", 1).startswith("flagged: your is_success calls oneshot.")
    assert total(output, "wrapper.py") == "0/10 correct, 2 attempted, 2 flagged"


def test_patching_the_judge_in_the_submission_changes_nothing(graded):
    verdict, output, _, _ = graded
    assert verdict("patcher.py", 1).startswith("not yet: you judge the whole episode")
    assert verdict("patcher.py", 9) == "not yet: on 439 successes of 480 trials, your lower bound is 0; expected 0.88617"


@needs_landlock
def test_a_submission_cannot_write_delete_read_connect_or_signal_outside(graded):
    verdict, _, outside, _ = graded
    assert verdict("writer.py", 1).startswith("not yet: your is_success raised RuntimeError: could W0 D0 R0 O0 N0 K0")
    assert not (outside / "owned.txt").exists() and (outside / "victim.txt").read_text() == "the teacher's"


def test_a_process_in_a_session_of_its_own_is_ended_with_the_submission(graded):
    verdict, _, _, survivors = graded
    assert verdict("escaper.py", 1) == "timed out after 2 s (an endless loop?)"
    assert survivors == []


def test_a_patched_attempt_that_calls_the_package_is_flagged_not_a_crash(graded):
    verdict, output, _, _ = graded
    assert verdict("attempter.py", 9).startswith("flagged: your wilson_interval calls oneshot.training.scoring.")
    assert total(output, "attempter.py") == "0/10 correct, 1 attempted, 1 flagged"


def test_printing_past_the_file_size_limit_costs_nothing(graded):
    """Output went to a log under the sandbox's 64 MB file-size limit: print() then raised OSError (Errno
    27, file too large) inside the student's function, and a correct submission scored 0."""
    verdict, _, _, _ = graded
    assert verdict("talker.py", 1) == "correct" and verdict("talker.py", 9) == "correct"


def test_memory_is_limited(graded):
    verdict, _, _, _ = graded
    assert verdict("hog.py", 1).startswith("not yet: your is_success raised MemoryError")


def test_limits_stay_under_the_graders_own_hard_limits():
    """Run under `ulimit -v` (a hard address-space limit), `limit` asking for more memory than that keeps
    the lower limit instead of failing: `--memory 9000` under `ulimit -v 6000000` failed every submission
    ("not allowed to raise maximum limit"); under no limit it sets what it is asked."""
    script = ("import resource, sys\n"
              "hard = int(sys.argv[1])\n"
              "if hard: resource.setrlimit(resource.RLIMIT_AS, (hard, hard))\n"
              "from oneshot.exercises import confine\n"
              "confine.limit(9000 << 20, 5, 50)\n"
              "print(*resource.getrlimit(resource.RLIMIT_AS))\n")
    for hard in (6_000_000_000, 0):
        done = subprocess.run([sys.executable, "-c", script, str(hard)], capture_output=True, text=True, timeout=60,
                              env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent)))
        assert done.returncode == 0, done.stderr
        soft, now = map(int, done.stdout.split())
        assert soft == now and (soft == hard if hard else 9000 << 20 < soft < (9000 << 20) + (4 << 30)), soft


def test_processes_are_limited(graded):
    _, output, _, _ = graded
    line = next(line for line in output.splitlines() if line.startswith("forker.py") and "spawned" in line)
    assert int(line.rsplit(" ", 1)[1]) < 32, line


def test_the_grader_run_from_the_class_folder_imports_no_student_module(tmp_path):
    for name in ("numpy.py", "tqdm.py", "json.py", "csv.py"):
        (tmp_path / name).write_text(f"import sys\nsys.stderr.write('SHADOW {name} RAN\\n')\n"
                                     f"raise ImportError('a student module')\n")
    (tmp_path / "alice.py").write_text(RIGHT_9)
    run = _grade_command("grade", ".", "--timeout", "5", cwd=tmp_path)
    assert run.returncode == 0 and "SHADOW" not in run.stderr, run.stderr[-2000:]
    assert "alice.py   9  correct" in run.stdout
    assert any(line.startswith("numpy.py") and line.endswith("-  could not load numpy.py: ImportError: a student "
                                                             "module") for line in run.stdout.splitlines())


def _copies():
    """The sandboxes' working copies in the temporary folder."""
    return set(Path(tempfile.gettempdir()).glob("oneshot-grade-*"))


def test_killing_the_grader_ends_every_process_a_submission_started(tmp_path):
    tag, before = f"orphan-{os.getpid() % 100000}", _copies()
    (tmp_path / "loop.py").write_text(ESCAPER.replace("escapee-{tag}", tag))
    grader = subprocess.Popen([sys.executable, "-m", "oneshot.exercises", "grade", str(tmp_path), "--timeout", "60"],
                              env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while not _marked(tag) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _marked(tag), "the submission never started"
        grader.kill()                                  # kill -9: no handler of the grader's runs
        grader.wait()
        deadline = time.monotonic() + 5
        while (_marked(tag) or _copies() - before) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _marked(tag) == [] and _copies() - before == set()         # nothing left running, nor on disk
    finally:
        grader.kill()
        _kill_marked(tag)


@pytest.mark.parametrize("how", sorted(EXITS))
def test_check_does_not_take_an_exit_for_success(tmp_path, how):
    (tmp_path / "exits.py").write_text(EXITS[how])
    run = _grade_command("check", "1", "--file", str(tmp_path / "exits.py"), "--timeout", "5")
    assert run.returncode == 1, (run.stdout, run.stderr)
    assert run.stdout.startswith("exercise 1: not yet: ")
    assert ("raised SystemExit: 0" if how == "sys_exit" else "crashed Python (exit status 0)") in run.stdout


@pytest.mark.parametrize("flag", [["--jobs", "-1"], ["--jobs", "0"], ["--timeout", "nan"], ["--timeout", "inf"],
                                  ["--timeout", "-1"], ["--timeout", "0"], ["--timeout", "1e19"], ["--timeout", "86401"]])
def test_bad_grader_flags_are_one_line_errors(tmp_path, capsys, flag):
    (tmp_path / "alice.py").write_text(RIGHT_9)
    with pytest.raises(SystemExit) as stop:
        cli_main.main(["grade", str(tmp_path), *flag])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.startswith(f"error: argument {flag[0]}: ") and err.count("\n") == 1, err


def test_the_grader_reads_only_values_from_the_sandbox():
    from oneshot.exercises import wire
    value = {"w": (1, 2.5, None, True), "a": __import__("numpy").arange(6.0).reshape(2, 3)}
    back = wire.decode(json.loads(json.dumps(wire.encode(value))))
    assert back["w"] == (1, 2.5, None, True) and back["a"].tolist() == [[0, 1, 2], [3, 4, 5]]
    import numpy as np
    objects = {"array": "|O8", "shape": [1], "data": "AAAAAAAAAAA="}
    short = {"array": "<f8", "shape": [2], "data": "AAAAAAAAAAA="}
    for hostile in [objects, short, {"pickle": "gASVAAAA"}, {"tuple": "not a list"}, {"dict": [[["k"], 1]]},
                    {"array": "<f8", "shape": [-1], "data": ""}, [1, 2]]:
        with pytest.raises(wire.WireError):
            wire.decode(hostile)
    assert np.isnan(wire.decode(json.loads(json.dumps(wire.encode(float("nan"))))))
    frames = wire.Frames()
    with pytest.raises(wire.WireError):
        frames.feed(b"\xff\xff\xff\xff")               # a 4 GB frame is refused before it is read
    assert wire.clean("ok\x1b[2J\nalice.py  1  correct") == "ok?[2J?alice.py  1  correct"


def test_the_log_keeps_its_newest_megabyte_and_is_a_real_text_stream(tmp_path):
    """The worker's sys.stdout and sys.stderr: never past its limit (the sandbox's 64 MB file-size limit
    made print() raise), the newest line at its end (a crash's last line, which the grader shows), and
    a text stream as Python's own is: encoding, buffer, fileno, reconfigure, a TypeError for bytes."""
    with open(tmp_path / "log", "w+b") as log:
        stream = worker.log_stream(log.fileno(), limit=1000)
        for i in range(2000):
            print(f"line {i}", file=stream)
        stream.flush()                               # text, then bytes: in order once flushed, as for sys.stdout
        stream.buffer.write(b"bytes\n")
        stream.reconfigure(encoding="utf-8")
        print("Traceback: the last line", file=stream)
        stream.flush()
        size = os.fstat(log.fileno()).st_size
        log.seek(0)
        text = log.read().decode()
        assert stream.encoding == "utf-8" and stream.fileno() == log.fileno()
        with pytest.raises(TypeError):
            stream.write(b"not text")
    assert 500 <= size <= 1000 and text.endswith("line 1999\nbytes\nTraceback: the last line\n")
