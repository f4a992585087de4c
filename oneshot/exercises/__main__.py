"""The exercises from a shell.

    python -m oneshot.exercises list                              the exercises, and the function each asks for
    python -m oneshot.exercises check 5 --file my_solution.py     check one function (the file defines it by name)
    python -m oneshot.exercises grade DIR [--timeout 60] [--jobs N]   (or --grade DIR) grade a class

Exit status of `check`: 0 correct, 1 not yet, 2 bad input (a missing file, a file that fails to load
or does not define the function); one line says which. `check` runs the student's code in this
process, as `oneshot.exercises.check` does in a notebook; `grade` runs each submission in its own
process with a timeout (`oneshot.exercises.grading`), and exits 0 once every submission is graded.
"""
import argparse
import sys

from oneshot.exercises import EXERCISES
from oneshot.exercises.grading import SubmissionError, child, grade, judge, load_functions


def _list():
    for n, e in EXERCISES.items():
        print(f"{n:>2}  {e.title:<50}  def {e.name}({e.signature})")
    return 0


def _check(number, file):
    if number not in EXERCISES:
        return _bad(f"there is no exercise {number}; the exercises are {min(EXERCISES)}-{max(EXERCISES)}")
    exercise = EXERCISES[number]
    try:
        functions = load_functions(file)
    except SubmissionError as e:
        return _bad(str(e))
    if exercise.name not in functions:
        return _bad(f"{file} defines no function {exercise.name}: exercise {number} asks for "
                    f"def {exercise.name}({exercise.signature})")
    result = judge(number, functions[exercise.name])
    print(result.line)
    return 0 if result.passed else 1


def _grade(folder, timeout, jobs):
    try:
        grade(folder, timeout, jobs)
    except SubmissionError as e:
        return _bad(str(e))
    return 0


def _bad(message):
    print(f"error: {message}", file=sys.stderr)
    return 2


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m oneshot.exercises", description=__doc__.splitlines()[0])
    parser.add_argument("--grade", metavar="DIR", help="grade every submission in DIR (as the grade command)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds each exercise may take when grading")
    parser.add_argument("--jobs", type=int, default=None, help="submissions graded at once (default: the cores)")
    commands = parser.add_subparsers(dest="command", metavar="{list,check,grade}")
    commands.add_parser("list", help="the exercises")
    one = commands.add_parser("check", help="check one exercise's function, defined in a file")
    one.add_argument("number", type=int)
    one.add_argument("--file", required=True, help="a .py file (or a folder of them) defining the function")
    many = commands.add_parser("grade", help="grade every submission (.py file or folder) in DIR")
    many.add_argument("dir")
    many.add_argument("--timeout", type=float, default=argparse.SUPPRESS)
    many.add_argument("--jobs", type=int, default=argparse.SUPPRESS)
    inner = commands.add_parser("_grade-child")                  # internal: one submission, in its own process
    inner.add_argument("path")
    inner.add_argument("numbers")
    args = parser.parse_args(argv)
    if args.command == "_grade-child":
        child(args.path, [int(n) for n in args.numbers.split(",")])
        return 0
    if args.command == "grade" or (args.grade and args.command is None):
        return _grade(args.dir if args.command == "grade" else args.grade, args.timeout, args.jobs)
    if args.command == "check":
        return _check(args.number, args.file)
    if args.command == "list":
        return _list()
    parser.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
