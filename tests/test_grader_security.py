"""The grader is a security boundary (issue 30, class 7): a class of hostile submissions, graded as a
teacher would (`python -m oneshot.exercises grade DIR`), and what each must NOT achieve: fake verdicts
printed to stdout, wrappers around the package's own answers (even ones that catch the tripwire), a
patched judge, files written or deleted outside its copy, another student's file read or linked in, the
teacher's environment seen, a process that outlives the grading (even in a session of its own, even
when the grader is killed), unlimited memory, CPU, files or processes, a student's numpy.py run by the
grader itself, a frame or text from the sandbox that crashes the grader or the teacher's terminal,
`check` taking sys.exit(0) for success, and flags that make no sense. An honest submission in the same
class is graded correct, so the confinement does not break what it must not."""
import ctypes
import errno
import json
import os
import re
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

import oneshot
from helpers import RIGHT_1, RIGHT_9
from oneshot.exercises import CHECKERS, EXERCISES, grading, sandbox, wire, worker
from oneshot.exercises import __main__ as cli_main
from oneshot.exercises.checking import Outcome

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
import ctypes, os, time
if os.fork() == 0:                           # a grandchild in a session of its own, spinning
    os.setsid()
    if os.fork() == 0:
        ctypes.CDLL(None).prctl(15, b"escapee-{tag}", 0, 0, 0)
        while True:
            pass
    os._exit(0)
if os.fork() == 0:                           # a child, sleeping, with a child of its own: the supervisor
    os.fork()                                # adopts the grandchild only once it has killed the child
    ctypes.CDLL(None).prctl(15, b"escapee-{tag}", 0, 0, 0)
    time.sleep(60)
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
PROBE = """
import math, os, resource, signal
import numpy as np
import oneshot.world.reach as reach
def is_success(end_effector, target, success_radius=0.05):
    try:
        reach.is_success(end_effector, target, success_radius)      # the package's answer, its trip caught
    except BaseException:
        pass
    e = np.asarray(end_effector)
    return bool(np.linalg.norm(e[-max(1, len(e) // 5):] - target, axis=-1).min() <= success_radius)
def conv2d(x, w, b, stride):                     # what the sandbox looks like from inside, in words
    facts = [f"secret={int(any('teacher-secret' in v for v in os.environ.values()))}",
             f"session={int(os.getsid(0) == os.getppid())}", f"cpu={resource.getrlimit(resource.RLIMIT_CPU)[0]}",
             f"fsize={resource.getrlimit(resource.RLIMIT_FSIZE)[0]}",
             f"core={resource.getrlimit(resource.RLIMIT_CORE)[0]}"]
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (1000, hard))
    try:
        with open("mine.bin", "wb") as f:        # in its working copy: allowed, up to the file-size limit
            f.write(b"x" * 2000)
        facts.append("write=ok")
    except OSError as e:
        facts.append(f"write={e.errno}")
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    raise RuntimeError(" ".join(facts))
def contextual_input(images, demo_images):
    print("a line before the last", flush=True)
    print("the last line \\x1b[31m", flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
def wilson_interval(successes, trials, z=1.96):
    os.write(1, b"what a C library prints\\n")    # fd 1 is the log, not the grader's channel
""" + RIGHT_9.split("z=1.96):\n", 1)[1] + """
def lstm_step(w_h, xw, h, c):
    return np.zeros(1 << 20), np.zeros(1)        # 8 MB: more than an answer's share of a frame
"""
SECOND = "def wilson_interval(successes, trials, z=1.96):\n    return 0.0, 1.0\n"
IMPORTER = RIGHT_9 + "import oneshot.exercises\noneshot.exercises.reference(9)(1, 2)\n"
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


def _grade_command(*args, cwd=None, timeout=120, env=ENV, preexec_fn=None):
    return subprocess.run([sys.executable, "-m", "oneshot.exercises", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=timeout, preexec_fn=preexec_fn)


def _allow_core_files():
    """In the grader's process: core files of up to 1 MB, as a teacher's shell may allow (`ulimit -c`)."""
    hard = resource.getrlimit(resource.RLIMIT_CORE)[1]
    soft = 1 << 20 if hard == resource.RLIM_INFINITY else min(1 << 20, hard)
    resource.setrlimit(resource.RLIMIT_CORE, (soft, hard))


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """One grading of a class of hostile submissions: (verdict(who, n), the output, the folder). The class
    is in a folder on the grader's sys.path (a course repository on PYTHONPATH), which the sandbox may
    read: only the grader's hiding keeps one submission from reading another's; and the teacher's
    environment holds a secret, and allows core files."""
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
               "attempter.py": ATTEMPTER, "probe.py": PROBE, "importer.py": IMPORTER}
    for name, source in sources.items():
        (folder / name).write_text(source)
    for name, source in (("kate/a.py", RIGHT_9), ("kate/b.py", SECOND), ("mallory/main.py", "from answer import *\n")):
        (folder / name).parent.mkdir(exist_ok=True)
        (folder / name).write_text(source)
    (folder / "mallory" / "answer.py").symlink_to(folder / "alice.py")        # another student's answers
    env = {**ENV, "PYTHONPATH": os.pathsep.join((ROOT, str(base))), "TEACHER_TOKEN": "teacher-secret"}
    try:
        run = _grade_command("grade", str(folder), "--timeout", "2", "--jobs", "2", env=env,
                             preexec_fn=_allow_core_files)
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


def load_error(output, who):
    return next(line.split(None, 2)[2] for line in output.splitlines() if line.split()[:2] == [who, "-"])


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


def test_a_tripwire_caught_by_the_submission_still_flags_it_and_only_that_exercise(graded):
    """probe.py's is_success calls the package's answer, catches what it raises, and returns its own right
    value: flagged all the same; its conv2d, the next exercise in the same sandbox, is judged on what it
    did (it raised), not flagged."""
    verdict, _, _, _ = graded
    assert verdict("probe.py", 1).startswith("flagged: your is_success calls oneshot.world.reach.is_success, ")
    assert verdict("probe.py", 4).startswith("not yet: your conv2d raised RuntimeError: secret=")


def test_the_sandbox_is_confined_as_its_docstring_says(graded):
    """What probe.py's conv2d saw from inside (timeout 2 s, every exercise): none of the teacher's
    environment (a secret in it), a session of its own (its supervisor's), CPU time at most the wall-clock
    budget of the exercises, files of at most 64 MB, and its working copy writable, where a write past the
    file-size limit (lowered to 1000 bytes by the probe) fails with OSError EFBIG, which the student's code
    can catch."""
    verdict, _, _, _ = graded
    facts = dict(re.findall(r"(\w+)=(-?\d+|ok)", verdict("probe.py", 4)))
    assert facts["secret"] == "0" and facts["session"] == "1", facts
    assert 0 < int(facts["cpu"]) <= 2 * (len(EXERCISES) + 1) + 2 and 0 < int(facts["fsize"]) <= 64 << 20, facts
    assert facts["write"] == str(errno.EFBIG), facts


def test_the_sandbox_writes_no_core_files(graded):
    """No core files in the sandbox, though the teacher's shell allows 1 MB of them (`_allow_core_files`).
    Where the hard limit is already 0 the grader's own limit cannot show, so the test says so by skipping."""
    if resource.getrlimit(resource.RLIMIT_CORE)[1] == 0:
        pytest.skip("core files are off at the hard limit here: the sandbox's 0 would show nothing of its own")
    verdict, _, _, _ = graded
    assert dict(re.findall(r"(\w+)=(-?\d+|ok)", verdict("probe.py", 4)))["core"] == "0"


def test_a_crash_shows_its_signal_and_its_last_line_made_safe(graded):
    """probe.py's contextual_input prints two lines, the last with an escape sequence, and kills itself:
    the verdict names the signal and the LAST line, its escape made '?'."""
    verdict, output, _, _ = graded
    assert verdict("probe.py", 8) == "crashed Python (killed by SIGKILL: the last line ?[31m)"
    assert "\x1b" not in output


def test_what_a_submission_writes_to_fd_1_does_not_reach_the_grader(graded):
    """os.write(1, ...), as a C library's printf does: fd 1 is the log, so wilson_interval is still correct."""
    verdict, _, _, _ = graded
    assert verdict("probe.py", 9) == "correct"


def test_an_answer_too_large_for_the_channel_is_said_to_be_so(graded):
    """8 MB per case, 3 cases: each answer is replaced by words, and the verdict says what happened,
    instead of a frame too large for the channel ("wrote into the grader's channel")."""
    verdict, _, _, _ = graded
    assert re.fullmatch(r"not yet: on a batch of 3, 4 units, your function returns a result of more than \d+ MB; "
                        r"expected a tuple of 2: \(h', c'\)", verdict("probe.py", 10)), verdict("probe.py", 10)


def test_a_folder_is_graded_on_its_own_files_only(graded):
    """kate/: a.py right, b.py wrong, both defining wilson_interval: the first in name order counts.
    mallory/: main.py imports answer.py, a symbolic link to alice.py, another student's file: the link
    is neither copied nor loaded, so main.py cannot import it."""
    verdict, output, _, _ = graded
    assert verdict("kate/", 9) == "correct"
    assert load_error(output, "mallory/") == "could not load main.py: ModuleNotFoundError: No module named 'answer'"
    assert total(output, "mallory/") == "0/10 correct, 0 attempted"


def test_calling_the_package_as_it_loads_is_a_load_error(graded):
    """importer.py defines wilson_interval, then calls reference(9) at import: not graded on what it defined."""
    _, output, _, _ = graded
    assert load_error(output, "importer.py") == ("could not load importer.py: PackageUsed: oneshot.exercises.solutions."
                                                 "wilson_interval is the package's own answer: write your own")


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
    value = {"w": (1, 2.5, None, True), "a": __import__("numpy").arange(6.0).reshape(2, 3)}
    back = wire.decode(json.loads(json.dumps(wire.encode(value))))
    assert back["w"] == (1, 2.5, None, True) and back["a"].tolist() == [[0, 1, 2], [3, 4, 5]]
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


def test_the_grader_refuses_frames_that_would_crash_it():
    """What only a submission writing into the channel itself could send: each is a WireError (the
    sandbox's ending "channel", scored 0), never an exception that ends the grading of the class: a result
    with fewer or more outcomes than the exercise has cases (judge would index past them), a frame that
    is a JSON list, an array shape of negative numbers NumPy cannot reshape to, or one nested too deeply."""
    right = {"value": {"tuple": [0.5, 0.75]}, "changed": None}
    cases = len(CHECKERS[9].cases())
    assert len(grading._valid({"event": "result", "exercise": 9, "outcomes": [right] * cases}, 9)["outcomes"]) == cases
    for count in (1, cases - 1, cases + 1):
        with pytest.raises(wire.WireError):
            grading._valid({"event": "result", "exercise": 9, "outcomes": [right] * count}, 9)
    with pytest.raises(wire.WireError):
        wire.Frames().feed(b"\x00\x00\x00\x03[1]")
    with pytest.raises(wire.WireError):
        wire.decode({"array": "<f8", "shape": [-2, -1], "data": "AAAAAAAAAAAAAAAAAAAAAA=="})     # 16 bytes
    deep = 1.0
    for _ in range(wire.MAX_DEPTH + 2):
        deep = {"list": [deep]}
    with pytest.raises(wire.WireError):
        wire.decode(deep)


def test_the_sandboxs_words_are_made_safe_before_the_grader_prints_them():
    """A load error, a notebook's notes and a submission's file name, as the sandbox or the teacher's folder
    give them, reach the terminal and the gradebook without control characters (an escape sequence could
    clear the screen or recolour a fake verdict)."""
    message = "could not load x.py: \x1b[2Jx.py  9  correct"
    loaded = grading._valid({"event": "load-error", "message": message}, "loaded")
    assert loaded["message"] == "could not load x.py: ?[2Jx.py  9  correct"
    notes = grading._valid({"event": "loaded", "notes": ["cell 3 raised \x1b[31mOops\rok", 5]}, "loaded")["notes"]
    assert notes == ["cell 3 raised ?[31mOops?ok"]
    assert grading._label("/class/\x1b[2Jeve\n.py") == "?[2Jeve?.py"


def test_a_function_not_written_on_every_case_is_not_a_stub():
    """"not written" (not counted as attempted) is the stub as handed out, raising NotImplementedError on
    every case; a function that raises it on one case only is attempted, and not yet right."""
    cases = len(CHECKERS[9].cases())
    stub = grading.verdict(9, [Outcome(not_written=True)] * cases)
    assert stub == "not written: wilson_interval raises NotImplementedError, as the stub does"
    partial = grading.verdict(9, [Outcome(not_written=True)] + [Outcome(value=(0.0, 1.0))] * (cases - 1))
    assert partial == "not yet: wilson_interval is not written yet (it raises NotImplementedError)"
    one = grading.Graded("x.py", [9, 1], {9: partial, 1: "missing"})
    assert grading.report(one)[-1].endswith("total  0/2 correct, 1 attempted")


def test_the_sandbox_may_read_python_even_when_the_class_folder_holds_it(tmp_path):
    """The class's folder is hidden from the sandbox, and the package's source always is; but a folder
    that holds Python itself (grading from /, or from a home holding the virtualenv) is not, or no
    submission could even start."""
    assert sandbox._hidden([tmp_path]) == [sandbox.PACKAGE, os.path.realpath(tmp_path)]
    assert sandbox._hidden([os.path.dirname(sys.prefix), "/"]) == [sandbox.PACKAGE]


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
