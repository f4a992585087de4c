"""Grading: each submission runs in a sandbox, and is judged here, on the values it returned.

Student code is untrusted: it may loop, crash, exhaust memory, fork, write files, print fake verdicts,
patch the checker or call the package's own answers. So the grader never imports it. `run_sandbox`
copies a submission into a fresh folder and starts `oneshot.exercises.worker` there, in a session of
its own, which confines itself (memory, CPU time, processes, files, network; `confine`), trips on the
package's answers (`poison`), and sends back over a pipe only the OUTCOMES of the student's functions
on the checkers' cases (`wire`: JSON values, never code). The grader computes the expected values
itself and judges (`checking.judge`), so nothing the submission prints or sends can make it correct
unless its functions' values are. A sandbox silent past its deadline (`timeout` seconds per exercise)
is ended, with everything it started; a new one checks the exercises left.
"""
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from oneshot.exercises import CHECKERS, EXERCISES, wire
from oneshot.exercises.checking import Outcome, expectations, judge
from oneshot.exercises.sandbox import Limits, run_sandbox, stopping
from oneshot.exercises.submissions import SubmissionError, submissions

_expected, _lock = {}, threading.Lock()


@dataclass
class Graded:
    """One submission's grade: `verdicts` {exercise: "correct" | "missing" | "not written: ..." |
    "not yet: ..." | "flagged: ..." | "timed out ..." | "crashed ..."} (missing and not written count as
    not attempted), or `load_error` when its code could not load; `notes` on its
    notebook cells that failed."""
    label: str
    numbers: list
    verdicts: dict = field(default_factory=dict)
    load_error: str = None
    notes: list = field(default_factory=list)

    def points(self, number):
        return int(self.verdicts.get(number) == "correct")

    @property
    def total(self):
        return sum(map(self.points, self.numbers))

    @property
    def flagged(self):
        return [n for n in self.numbers if str(self.verdicts.get(n, "")).startswith("flagged")]


def _valid(message, expected):
    """`message` if it is what the sandbox sends next (`expected`: "ready", "loaded" or an exercise
    number), its text made safe (`wire.clean`) and its outcomes decoded; else WireError."""
    event = message.get("event")
    if expected == "ready" and message == {"event": "ready"}:
        return message
    if expected == "loaded" and event == "load-error" and isinstance(message.get("message"), str):
        return {"event": event, "message": wire.clean(message["message"])}
    if expected == "loaded" and event == "loaded" and isinstance(message.get("notes"), list):
        return {"event": event, "notes": [wire.clean(n, 160) for n in message["notes"][:20] if isinstance(n, str)]}
    if event == "result" and message.get("exercise") == expected:
        if message.get("missing") is True:
            return {"event": event, "exercise": expected, "missing": True}
        outcomes, count = message.get("outcomes"), len(_expectations(expected)[0])
        if isinstance(outcomes, list) and len(outcomes) == count:
            return {"event": event, "exercise": expected,
                    "outcomes": [_outcome(o, EXERCISES[expected]) for o in outcomes]}
    raise wire.WireError(f"expected {expected!r}; got {str(message)[:80]!r}")


def _outcome(data, exercise):
    """An Outcome from the sandbox's data (wire.WireError if it is not one)."""
    if type(data) is dict and set(data) == {"used"} and isinstance(data["used"], str):
        return Outcome(used=wire.clean(data["used"], 120))
    if type(data) is dict and data == {"not_written": True}:
        return Outcome(not_written=True)
    if type(data) is dict and set(data) == {"error"} and isinstance(data["error"], str):
        return Outcome(error=wire.clean(data["error"], 240))
    if type(data) is dict and set(data) == {"value", "changed"} and data["changed"] in (None, *exercise.arguments):
        return Outcome(value=wire.decode(data["value"]), changed=data["changed"])
    raise wire.WireError("not an outcome")


def _expectations(number):
    """(cases, expected values) of exercise `number`, computed once per process."""
    with _lock:
        if number not in _expected:
            _expected[number] = expectations(CHECKERS[number])
        return _expected[number]


def verdict(number, outcomes):
    """The verdict on an exercise's outcomes: "correct", "not written: ..." (the stub as handed out: it
    raised NotImplementedError on every case), "not yet: ..." or "flagged: ..." (see `Graded`)."""
    if all(outcome.not_written for outcome in outcomes):
        return f"not written: {EXERCISES[number].name} raises NotImplementedError, as the stub does"
    cases, wants = _expectations(number)
    result = judge(EXERCISES[number], CHECKERS[number], outcomes.__getitem__, cases, wants)
    words = wire.clean(result.message, 2000)             # quotes the submission's values: no control characters
    return "correct" if result.passed else f"{'flagged' if result.flagged else 'not yet'}: {words}"


def _label(path):
    """A submission's name as the grade shows it, on one line: "alice.py", "carol/" (a folder) (`wire.clean`)."""
    return wire.clean(Path(path).name + ("/" if Path(path).is_dir() else ""), 120)


def grade_submission(path, numbers, limits=Limits(), hidden=()):
    """Grade one submission on exercises `numbers`: a Graded."""
    graded, pending = Graded(_label(path), list(numbers)), list(numbers)
    while pending and not stopping.is_set():
        try:
            messages, ending, why = run_sandbox(path, pending, limits, _valid, hidden)
        except (SubmissionError, OSError) as e:            # too large, unreadable: said, not fatal
            graded.load_error = wire.clean(f"could not copy it: {e}" if isinstance(e, OSError) else str(e))
            return graded
        loaded = False
        for message in messages:
            if message["event"] == "load-error":
                graded.load_error = message["message"]
                return graded
            if message["event"] == "loaded":
                loaded, graded.notes = True, graded.notes or message["notes"]
            if message["event"] == "result":
                number = pending.pop(0)
                graded.verdicts[number] = ("missing" + (f" ({graded.notes[0]})" if graded.notes else "")
                                           if message.get("missing") else verdict(number, message["outcomes"]))
        if not pending or ending == "stopped":
            return graded
        trouble = {"timeout": f"timed out after {limits.timeout:g} s (an endless loop?)",
                   "channel": "wrote into the grader's channel (only the sandbox may)",
                   }.get(ending, f"crashed Python ({why})")
        if not loaded:
            slow = " (if it only loads slowly, raise --timeout)" if ending == "timeout" else ""
            graded.load_error = (f"crashed while loading ({why})" if ending == "crash" else
                                 f"{trouble} while loading{slow}")
            return graded
        graded.verdicts[pending.pop(0)] = trouble           # the exercise it was on; a new sandbox does the rest
    return graded


def grade(folder, numbers=None, limits=Limits(), jobs=None, out=print, found=None):
    """Grade every submission in `folder` on exercises `numbers` (default: all): one line per submission
    and exercise, then a total, printed in name order as they finish. Returns [Graded]. `found`: the
    submissions, if the caller has listed them already (`submissions(folder)`)."""
    found, numbers = found or submissions(folder), sorted(numbers or EXERCISES)
    width, graded = max(len(_label(p)) for p in found), []
    for number in numbers:
        _expectations(number)
    stopping.clear()
    with ThreadPoolExecutor(min(jobs or os.cpu_count() or 1, len(found))) as pool:
        try:
            for one in pool.map(lambda p: grade_submission(p, numbers, limits, hidden=[folder]), found):
                for line in report(one, width):
                    out(line)
                graded.append(one)
        except BaseException:
            stopping.set()                              # Ctrl-C: every sandbox is ended within a second,
            pool.shutdown(wait=False, cancel_futures=True)          # and none is started
            raise
    return graded


def report(graded, width=0):
    """A Graded's lines: one per exercise (or its load error), then its total."""
    label = f"{graded.label:<{width}}"
    lines = [f"{label}   -  {graded.load_error}"] if graded.load_error else \
        [f"{label}  {n:>2}  {graded.verdicts[n]}" for n in graded.numbers]
    attempted = sum(not str(v).startswith(("missing", "not written")) for v in graded.verdicts.values())
    flagged = f", {len(graded.flagged)} flagged" if graded.flagged else ""
    return lines + [f"{label}  total  {graded.total}/{len(graded.numbers)} correct, {attempted} attempted{flagged}"]
