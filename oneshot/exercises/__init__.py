"""Exercises on MIL, each a function the student writes, with a checker that says what is wrong.

Ten exercises cover the paper's parts in reading order (`python -m oneshot.exercises list`):

    1-3   the world and the expert (Section IV): the success criterion, the arm's kinematics and
          Jacobian, one iLQG backward-pass step             notebooks/exercises/01_world_and_expert.ipynb
    4-7   the network and MAML (Sections II-IV): im2col convolution, eq. (2), eq. (1), second- and
          first-order meta-gradients                        notebooks/exercises/02_network_and_maml.ipynb
    8-10  the baselines and evaluation (Section IV): the contextual input, the Wilson interval, an
          LSTM step                                         notebooks/exercises/03_baselines.ipynb

From a notebook: `check(5, imitation_loss)` prints one line, "exercise 5 (eq. 2, the imitation loss):
correct" or "exercise 5: not yet: <the first difference, in words>", and returns a `Result` (passed,
message). The checker runs the function on random and edge-case inputs and compares it with the
package's own function (`oneshot.maml.imitation.imitation_loss` here); when it differs, it names the known
mistake that explains the difference, if one does. `EXERCISES[n]` says what exercise n asks for;
`reference(n)` is its reference solution (for teachers; `oneshot/exercises/solutions.py`).
From a shell: `python -m oneshot.exercises check 5 --file my_solution.py`, and `grade DIR` for a
class (`oneshot/exercises/__main__.py`), both in a sandbox: `grading`, `sandbox`, `worker`, `confine`,
`poison`, `wire`, `submissions`, `gradebook`.
"""
import os as _os
import sys as _sys

if _sys.argv[:1] == ["-m"] and not _sys.flags.safe_path and _sys.path[:1] == [_os.getcwd()]:
    del _sys.path[0]       # `python -m oneshot.exercises grade .` from a class's folder: a student's numpy.py
    #                        there must not be imported as NumPy by the grader (python -P does the same)

from oneshot.exercises import checks_baselines, checks_maml, checks_network, checks_world, poison
from oneshot.exercises.catalogue import EXERCISES
from oneshot.exercises.checking import Exercise, Outcome, Result, attempt, run
from oneshot.exercises.solutions import SOLUTIONS

CHECKERS = {**checks_world.CHECKERS, **checks_network.CHECKERS, **checks_maml.CHECKERS, **checks_baselines.CHECKERS}
# Every function that computes an answer: a submission may not call them (`poison`).
ANSWERS = tuple(f for n in sorted(CHECKERS) for f in CHECKERS[n].package) + tuple(SOLUTIONS.values())

__all__ = ["EXERCISES", "Exercise", "Result", "check", "reference"]


def _exercise(number):
    if number not in EXERCISES:
        raise ValueError(f"there is no exercise {number!r}; the exercises are {min(EXERCISES)}-{max(EXERCISES)}")
    return EXERCISES[number]


def check(number, function, quiet=False):
    """Check the student's `function` for exercise `number`: print the verdict (unless quiet) and return
    a Result (passed: bool, message: "correct" or the first difference in words). Never raises on the
    student's account: a function that raises or returns the wrong shape is reported in words. A
    function that is, or calls, the package's own answer (`reference(n)` among them) is flagged, as
    the grader flags it (`poison.watching`)."""
    result = run(_exercise(number), CHECKERS[number], function, attempt=_watched_attempt)
    if not quiet:
        print(result.line)
    return result


def _watched_attempt(exercise, case, function):
    """`attempt`, the package's ANSWERS watched (`poison.watching`): its Outcome's `used` names the
    first of them the function called, even if it caught what that raised."""
    poison.tripped.clear()
    with poison.watching(ANSWERS, attempt.__code__):
        outcome = attempt(exercise, case, poison.submission(function))
    return Outcome(used=poison.tripped[0]) if poison.tripped and not outcome.used else outcome


def reference(number):
    """The reference solution (a function) of exercise `number`, for teachers: `check` flags it, and a
    function calling it, as the grader does; a student's copy of its code passes."""
    return SOLUTIONS[_exercise(number).number]
