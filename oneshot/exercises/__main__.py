"""The exercises from a shell.

    python -m oneshot.exercises list                            the exercises, their functions and notebooks
    python -m oneshot.exercises check 5 --file my_solution.py   check one function (a .py file or notebook defining it)
    python -m oneshot.exercises grade DIR [--exercises 5,6] [--csv grades.csv] [--json grades.json]
                                          [--timeout 10] [--memory 1000] [--jobs N]     grade a class

A submission is a .py file, a notebook (.ipynb, executed or not: its code cells, `submissions`) or a
folder of them. `check` and `grade` run it in a sandbox (`sandbox`, `worker`): its own process and
working copy, limits on time, memory and processes, no writes outside its copy, and the verdict made
here, from the values its functions returned, never from what it prints.

Exit status of `check`: 0 correct, 1 not yet (wrong, raised, timed out, crashed, flagged), 2 bad input
(a missing file, one that fails to load or does not define the function); one line says which.
`grade` exits 0 once every submission is graded, 2 on bad input, 130 when interrupted (Ctrl-C, SIGTERM).
"""
import argparse
import math
import os
import sys

from oneshot.exercises import EXERCISES, gradebook
from oneshot.exercises.grading import grade, grade_submission
from oneshot.exercises.sandbox import Limits, sandbox_gaps
from oneshot.exercises.submissions import SUFFIXES, SubmissionError, is_submission, passed_over, submissions
from oneshot.tools import cli

_BASELINE_MB = 300                 # what a sandbox maps before the submission runs (Python, NumPy, autograd)


MAX_SECONDS = 86400.0   # a day: the sandbox's CPU and alarm limits take whole seconds, and far longer overflows them


def seconds(text):
    """An argparse type: a number of seconds > 0 and at most MAX_SECONDS."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0 < value <= MAX_SECONDS):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0 and at most {MAX_SECONDS:g} (a day); "
                                         f"got {text!r}")
    return value


def exercise_list(text):
    """An argparse type: exercise numbers, e.g. "5,6" -> [5, 6]."""
    try:
        numbers = sorted({int(n) for n in text.split(",")})
    except ValueError:
        numbers = []
    if not numbers or not set(numbers) <= set(EXERCISES):
        raise argparse.ArgumentTypeError(f"expected comma-separated exercise numbers {min(EXERCISES)}-"
                                         f"{max(EXERCISES)}, e.g. 5,6; got {text!r}")
    return numbers


def _limits(args):
    return Limits(timeout=args.timeout, memory_mb=args.memory)


def _warn():
    for gap in sandbox_gaps():
        print(f"warning: {gap}", file=sys.stderr)


def _list():
    for n, e in EXERCISES.items():
        print(f"{n:>2}  {e.title:<50}  {e.notebook:<26}  def {e.name}({e.signature})")
    print("(the notebooks are in notebooks/exercises/; each exercise's stub is the cell tagged exercise-N)")
    return 0


def _check(args):
    if args.number not in EXERCISES:
        return _bad(f"there is no exercise {args.number}; the exercises are {min(EXERCISES)}-{max(EXERCISES)}")
    exercise = EXERCISES[args.number]
    if not is_submission(args.file):
        return _bad(f"no such file or folder: {args.file}" if not os.path.lexists(args.file) else
                    f"{args.file} is not a .py file, a notebook (.ipynb), or a folder of them")
    _warn()
    graded = grade_submission(args.file, [args.number], _limits(args), hidden=[_folder_of(args.file)])
    if graded.load_error:
        return _bad(graded.load_error)
    verdict = graded.verdicts[args.number]
    if verdict.startswith("missing"):
        return _bad(f"{args.file} defines no function {exercise.name}: exercise {args.number} asks for "
                    f"def {exercise.name}({exercise.signature})" + verdict[len("missing"):])
    if verdict == "correct":
        print(f"exercise {args.number} ({exercise.title}): correct")
        return 0
    said = verdict if verdict.startswith(("not yet", "not written", "flagged")) else "not yet: " + verdict
    print(f"exercise {args.number}: {said}")
    return 1


def _folder_of(file):
    return os.path.dirname(os.path.abspath(file))


def _grade(args):
    try:
        found = submissions(args.dir)
    except SubmissionError as e:
        return _bad(str(e))
    if args.csv and args.json and os.path.realpath(args.csv) == os.path.realpath(args.json):
        raise ValueError(f"--csv and --json both name {args.json}; name two files")
    for flag, path, kind in (("--csv", args.csv, "csv"), ("--json", args.json, "json")):
        if path:
            cli.not_an_input(path, found, flag, "a submission")
            if path.endswith(SUFFIXES):          # the next `grade` of its folder would grade it
                raise ValueError(f"{flag} {path} is named like a submission ({'/'.join(SUFFIXES)}); name it .{kind}")
            cli.replaces_only(path, lambda p, kind=kind: gradebook.is_gradebook(p, kind), flag,
                              f"a gradebook ({kind.upper()}) that grade wrote")
    jobs = min(args.jobs or os.cpu_count() or 1, len(found))
    cli.check_memory(jobs * (args.memory + _BASELINE_MB) << 20,
                     f"{jobs} submissions at once (--jobs) x --memory {args.memory} MB (+{_BASELINE_MB} MB each "
                     f"for Python)", "use fewer jobs or less memory")
    _warn()
    for name, why in passed_over(args.dir):
        print(f"warning: {name} is not graded: it is {why}, which the grader never follows or reads; "
              f"put the file itself in {args.dir}", file=sys.stderr)
    graded = grade(args.dir, args.exercises, _limits(args), args.jobs, found=found)    # Ctrl-C, SIGTERM: cli.run
    numbers = args.exercises or sorted(EXERCISES)
    for path, text in ((args.csv, gradebook.csv_text), (args.json, gradebook.json_text)):
        if path:
            gradebook.write(path, text(graded, numbers))
            print(f"wrote {path}")
    return 0


def _bad(message):
    print(f"error: {message}", file=sys.stderr)
    return 2


def parser():
    limits = cli.Parser(add_help=False)
    limits.add_argument("--timeout", type=seconds, default=Limits.timeout,
                        help=f"seconds each exercise may take, wall clock and CPU (default {Limits.timeout:g})")
    limits.add_argument("--memory", type=cli.at_least(50), default=Limits.memory_mb, metavar="MB",
                        help=f"memory a submission may use, MB (default {Limits.memory_mb})")
    main = cli.Parser(prog="python -m oneshot.exercises", description=__doc__.splitlines()[0])
    main.add_argument("--grade", metavar="DIR", help=argparse.SUPPRESS)        # gone: see `grade`
    commands = main.add_subparsers(dest="command", metavar="{list,check,grade}", parser_class=cli.Parser)
    commands.add_parser("list", help="the exercises, their functions, and the notebooks that hold them")
    one = commands.add_parser("check", parents=[limits], help="check one exercise's function, defined in a file")
    one.add_argument("number", type=cli.positive_int, help="the exercise (python -m oneshot.exercises list)")
    one.add_argument("--file", required=True, help="a .py file or notebook (or a folder of them) defining the function")
    many = commands.add_parser("grade", parents=[limits], help="grade every submission in DIR",
                               description="Grade every submission in DIR: its .py files, notebooks, and folders "
                                           "of them, one per student.")
    many.add_argument("dir")
    many.add_argument("--exercises", type=exercise_list, help="the assigned exercises, e.g. 5,6 (default: all)")
    many.add_argument("--jobs", type=cli.positive_int, default=None, help="submissions graded at once (default: the cores)")
    many.add_argument("--csv", type=cli.writable_file, metavar="FILE", help="also write a gradebook CSV")
    many.add_argument("--json", type=cli.writable_file, metavar="FILE", help="also write the grades as JSON")
    return main


def main(argv=None):
    args = parser().parse_args(argv)
    if args.grade:
        return _bad(f"--grade is gone: use python -m oneshot.exercises grade {args.grade}")
    if args.command == "grade":
        return _grade(args)
    if args.command == "check":
        return _check(args)
    if args.command == "list":
        return _list()
    parser().error("name a command: list, check or grade")


if __name__ == "__main__":
    sys.exit(cli.run(main))
