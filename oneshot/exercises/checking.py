"""What every checker shares: call the student's function safely on a list of cases, compare its
result with the package's own function, and say in words what the FIRST difference is, naming the
known mistake it matches when it matches one.

An exercise's checker is a `Checker`: the package's function (called like the student's), its cases
(random and edge-case inputs, each described in words), the shape of the result (`Out`), and the known
mistakes, each a wrong version of the function with the words that explain it. A difference is
"explained" by a mistake when the mistake's result equals the student's on the first case that shows
the difference; when several do, the one that agrees with the student on the most cases wins.

Running and judging are apart: `attempt` runs the student's function on one case and says what it
did (an `Outcome`: its value, or the error it raised, in words); `judge` turns the outcomes into a
verdict. `run` does both in this process (for a notebook's `check`); the grader runs `attempt` in a
sandboxed process and `judge` in its own, on the values that came back (`oneshot.exercises.grading`).
"""
import copy
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from oneshot.exercises.compare import Difference, Out, compare, describe, part_of


@dataclass(frozen=True)
class Exercise:
    """What a student sees: exercise `number` asks for `def name(signature)`, documented by `doc`."""
    number: int
    name: str          # the function the student defines, e.g. "imitation_loss"
    title: str         # e.g. "eq. 2, the imitation loss"
    section: str       # the paper's section, e.g. "III"
    signature: str     # e.g. "params, demo"
    doc: str           # the stub's docstring
    notebook: str = "" # the notebook of notebooks/exercises/ that holds it, e.g. "02_network_and_maml.ipynb"

    @property
    def arguments(self):
        """The argument names, e.g. ["params", "demo"]."""
        return [a.split("=")[0].strip() for a in self.signature.split(",")]

    @property
    def stub(self):
        """The stub a student starts from: the signature, the docstring, `raise NotImplementedError`."""
        first, *rest = self.doc.strip().splitlines()
        doc = "\n".join([first] + [("    " + line).rstrip() for line in rest])
        return (f'def {self.name}({self.signature}):\n    """{doc}\n    """\n'
                f'    raise NotImplementedError("exercise {self.number}: write {self.name}")\n')


@dataclass(frozen=True)
class Result:
    """A verdict: `passed`, and `message`: "correct", or the first difference in words."""
    exercise: int
    passed: bool
    message: str
    title: str = ""
    flagged: bool = False      # the function called the package's own answer (`oneshot.exercises.poison`)

    @property
    def line(self):
        """One line: "exercise 5 (eq. 2, the imitation loss): correct" or "exercise 5: not yet: ..."."""
        if self.passed:
            return f"exercise {self.exercise} ({self.title}): correct"
        return f"exercise {self.exercise}: not yet: {self.message}"

    def __str__(self):
        return self.line

    def _ipython_display_(self):
        """`check` has printed the verdict already; a notebook cell ending in `check(...)` shows it once."""


@dataclass(frozen=True)
class Case:
    """One input. label: the input in words ("a 5-frame demo"); args: the function's arguments;
    facts: numbers a mistake's words may quote ("{T}"); call(fn, *args): how the checker uses a
    function (default fn(*args), or e.g. its gradient); out: the result's shape if not the checker's;
    hint: words added when the student's function raises on this case, or gets it wrong in a way no
    known mistake explains (e.g. "q has leading axes: use q[..., 0]"), unless hint_only_on_error."""
    label: str
    args: tuple
    facts: dict = field(default_factory=dict)
    call: Callable = None
    out: Out = None
    hint: str = ""
    hint_only_on_error: bool = False        # the hint is about raising (e.g. "autograd cannot differentiate")

    def run(self, fn, args=None):
        args = self.args if args is None else args
        return fn(*args) if self.call is None else self.call(fn, *args)


@dataclass(frozen=True)
class Mistake:
    """A known wrong answer: its words (may quote a case's facts, "{T}") and a function computing it."""
    explain: str
    fn: Callable


@dataclass(frozen=True)
class Checker:
    """expected: the package's function, called like the student's; cases: () -> [Case] (seeded)."""
    expected: Callable
    cases: Callable
    out: Out
    mistakes: tuple = ()
    package: tuple = ()        # the package's functions this exercise reimplements: off limits when graded


# ----------------------------------------------------------------------------------------------------
# Running a checker
# ----------------------------------------------------------------------------------------------------


def _same(a, b):
    """Are two arguments unchanged copies of each other? (Arrays, dicts, tuples; other objects: yes.)"""
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, Mapping):
        return isinstance(b, Mapping) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return isinstance(b, (tuple, list)) and len(a) == len(b) and all(map(_same, a, b))
    return True


def error_words(error):
    """An exception in one line: "ZeroDivisionError: division by zero" (its name alone if its message
    cannot be had: a student's exception whose __str__ raises)."""
    try:
        text = str(error).strip().splitlines()
    except Exception:
        text = []
    text = text[0] if text else ""
    return f"{type(error).__name__}: {text[:200]}" if text else type(error).__name__


def _safe_compare(got, want, out):
    try:
        return compare(got, want, out)
    except Exception as e:
        return Difference(f"{out.what} is {describe(got)}, which the checker cannot read ({error_words(e)})")


@dataclass(frozen=True)
class Outcome:
    """What the student's function did on one case: returned `value`, or raised `error` (in words,
    "ZeroDivisionError: division by zero"; `not_written` for NotImplementedError); `changed` names
    the first argument it changed in place; `used` names the package's own function it called."""
    value: object = None
    error: str = None
    not_written: bool = False
    changed: str = None
    used: str = None

    @property
    def ok(self):
        return self.error is None and not self.not_written and self.used is None


def attempt(exercise, case, function):
    """Run `function` on a copy of `case`'s arguments: an Outcome, whatever the function does (it may
    raise anything, sys.exit() among it; only KeyboardInterrupt passes, as Ctrl-C should)."""
    args = copy.deepcopy(case.args)
    try:
        value = case.run(function, args)
    except NotImplementedError:
        return Outcome(not_written=True)
    except KeyboardInterrupt:
        raise
    except BaseException as e:          # noqa: B036: SystemExit too; PackageUsed carries `package_function`
        return Outcome(error=error_words(e), used=getattr(e, "package_function", None))
    changed = [a for a, before, after in zip(exercise.arguments, case.args, args) if not _same(before, after)]
    return Outcome(value=value, changed=changed[0] if changed else None)


def _try(case, fn):
    try:
        return True, case.run(fn, copy.deepcopy(case.args))
    except Exception:
        return False, None


def _explain(mistake, case):
    try:
        return mistake.explain.format(**case.facts)
    except (KeyError, IndexError, ValueError):
        return mistake.explain


def _diagnose(checker, cases, index, got, want, difference, outcome_of):
    """The known mistake that explains the student's result on cases[index], or None."""
    case = cases[index]
    out = case.out or checker.out
    mine, _ = part_of(got, out, difference.part)
    candidates = []
    for mistake in checker.mistakes:
        ok, theirs = _try(case, mistake.fn)
        if not ok or _safe_compare(theirs, want, out) is None:
            continue                                   # this mistake does not show on this case
        try:
            theirs, part_out = part_of(theirs, out, difference.part)
        except Exception:
            continue
        if _safe_compare(mine, theirs, part_out) is None:
            candidates.append(mistake)
    if len(candidates) <= 1:
        return candidates[0] if candidates else None
    student = [(o.ok, o.value) for o in map(outcome_of, range(len(cases)))]   # several fit: the one

    def agreement(mistake):
        score = 0
        for c, (ok, yours) in zip(cases, student):
            theirs_ok, theirs = _try(c, mistake.fn)
            score += ok and theirs_ok and _safe_compare(yours, theirs, c.out or checker.out) is None
        return score                                   # that fits the most cases wins
    return max(candidates, key=agreement)


def run(exercise, checker, function, attempt=attempt):
    """Check `function` against the package on every case, in this process: `judge` of its outcomes.
    attempt(exercise, case, function) -> Outcome: `attempt`, or `check`'s, which also watches for the
    package's answers (`oneshot.exercises`)."""
    if not callable(function):
        return Result(exercise.number, False, f"expected a function {exercise.name}({exercise.signature}); "
                                              f"got {describe(function)}", exercise.title)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        cases, outcomes = checker.cases(), {}

        def outcome_of(index):                         # run the function only on the cases judge asks for
            if index not in outcomes:
                outcomes[index] = attempt(exercise, cases[index], function)
            return outcomes[index]
        return judge(exercise, checker, outcome_of, cases)


def expectations(checker):
    """(cases, the package's result on each): what `judge` compares with, computed once per grading."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        cases = checker.cases()
        return cases, [case.run(checker.expected) for case in cases]


def judge(exercise, checker, outcome_of, cases, wants=None):
    """The verdict on the outcomes `outcome_of(index)` of the student's function on `cases` (the
    checker's): a Result with the first difference in words, naming the mistake that explains it."""
    def verdict(passed, message, flagged=False):
        return Result(exercise.number, passed, message, exercise.title, flagged)
    name = exercise.name
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        for index, case in enumerate(cases):
            out = case.out or checker.out
            want = case.run(checker.expected) if wants is None else wants[index]
            outcome = outcome_of(index)
            if outcome.used:
                return verdict(False, f"your {name} calls {outcome.used}, the package's own (on {case.label}): "
                                      f"write your own", flagged=True)
            if outcome.not_written:
                return verdict(False, f"{name} is not written yet (it raises NotImplementedError)")
            if outcome.error is not None:
                hint = f"; {case.hint}" if case.hint else ""
                return verdict(False, f"your {name} raised {outcome.error} on {case.label}{hint}")
            if outcome.changed:
                return verdict(False, f"your {name} changed its argument `{outcome.changed}` in place (on "
                                      f"{case.label}): leave the inputs as they are and return new values")
            difference = _safe_compare(outcome.value, want, out)
            if difference is None:
                continue
            mistake = _diagnose(checker, cases, index, outcome.value, want, difference, outcome_of)
            if mistake is not None:
                return verdict(False, f"{_explain(mistake, case)} (on {case.label}: {difference.message})")
            hint = f"; {case.hint}" if case.hint and not case.hint_only_on_error else ""
            return verdict(False, f"on {case.label}, {difference.message}{hint}")
    return verdict(True, "correct")
