"""Tripwires: in the sandbox, the package's own answers refuse to work for a submission (`arm`); in a
notebook, `check` watches for them instead and flags them the same way (`watching`).

A submission that wraps `oneshot.exercises.reference(5)`, or the package's `imitation_loss` or
`inner_update`, would otherwise be graded correct. Before a submission loads, `arm` swaps the code of
every function that computes an answer (`Checker.package`: each exercise's package functions, every
function of their modules, and the reference solutions) for a tripwire. The tripwire looks up the
stack: if a submission's frame called it (directly, or through any other package function), it raises
`PackageUsed`, which the sandbox reports as "your imitation_loss calls oneshot.maml.imitation.
imitation_loss, the package's own"; otherwise (the checker's own code, or autograd's backward pass)
it runs the original. The functions of `ALLOWED` modules are the exception exercise 5 needs: its loss
calls `oneshot.policy.network.forward`, whose convolution is exercise 4's answer.

Swapping the code object, not the module attribute, trips every alias: `from ... import`, `reference(n)`,
`SOLUTIONS`, `Checker.expected`. This stops a submission from USING the package's answers; it cannot stop
one that deliberately digs the originals out of this process's memory (any code in a process can), and
the grader trusts nothing this process says: it judges the values that come back (`grading`).
"""
import contextlib
import gc
import os
import sys
import sysconfig
import threading
import types

ALLOWED = ("oneshot.policy.network",)       # modules whose functions a submission may call: entry points
tripped = []                                # names of the answers a submission called, newest last
_state = {"originals": {}, "names": {}, "entries": set(), "boundary": None, "trusted": (), "seen": {}, "watched": {}}


class PackageUsed(BaseException):
    """A submission called one of the package's answers. A BaseException, so that `except Exception`
    in the submission does not hide it; `package_function` names the function."""

    def __init__(self, name):
        super().__init__(f"{name} is the package's own answer: write your own")
        self.package_function = name


def submission(function):
    """`function` (the student's), wrapped in a frame the tripwires count as the submission's: so that
    `wilson_interval = reference(9)`, whose calls come straight from the checker, trips too."""
    def submitted(*args, **kwargs):
        return function(*args, **kwargs)
    return submitted


_SUBMITTED = submission(None).__code__


def _trusted_roots():
    """Folders whose code is not a submission's: the standard library, site-packages, the oneshot package."""
    import oneshot
    roots = {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    roots |= {os.path.dirname(oneshot.__file__)} | {p for p in sys.path if "site-packages" in p}
    return tuple(os.path.join(os.path.realpath(r), "") for r in roots if r)


def _is_trusted(filename):
    seen = _state["seen"]
    if filename not in seen:
        seen[filename] = filename[:1] == os.sep and os.path.realpath(filename).startswith(_state["trusted"])
    return seen[filename]


def _by_submission(frame):
    """Did a submission's frame (or `submission`'s wrapper) make this call, `frame` being the caller's,
    with no `ALLOWED` function between? Reaching the checker's boundary without one means the checker
    made it (autograd's backward pass, say); a thread a submission started has no boundary above it."""
    while frame is not None:
        code = frame.f_code
        if code in _state["entries"] or code is _state["boundary"]:
            return False
        if code is _SUBMITTED or not _is_trusted(code.co_filename):
            return True                         # a submission's frame (a file of its own, or exec'd text)
        frame = frame.f_back
    return True


def trip(key, args, kwargs):
    """What a tripwire does (called by the swapped code): run the original, unless a submission called
    it (`_by_submission`): then raise PackageUsed."""
    if not _by_submission(sys._getframe(2)):   # 0: here, 1: the tripwire, 2: its caller
        return _state["originals"][key](*args, **kwargs)
    tripped.append(_state["names"][key])
    raise PackageUsed(_state["names"][key])


def _modules_of(functions):
    return {getattr(sys.modules.get(f.__module__), "__file__", None) for f in functions
            if f.__module__ not in ALLOWED} - {None}


def _targets(functions, boundary):
    """The answers: `functions` and every closure-free function defined in their modules' files (not
    ALLOWED modules'); and the rule's state: the boundary, the trusted folders, the ALLOWED entries."""
    files = {os.path.realpath(f) for f in _modules_of(functions)}
    explicit = {id(f) for f in functions}
    targets = [f for f in gc.get_objects() if type(f) is types.FunctionType and f.__closure__ is None and
               (id(f) in explicit or os.path.realpath(f.__code__.co_filename) in files)]
    _state.update(boundary=boundary, trusted=_trusted_roots())
    for module in ALLOWED:
        _state["entries"] |= {f.__code__ for f in vars(sys.modules[module]).values() if type(f) is
                              types.FunctionType and f.__module__ == module and id(f) not in explicit}
    return targets


@contextlib.contextmanager
def watching(functions, boundary):
    """The tripwires' rule in the student's own process (a notebook's `check`), where nothing may stay
    swapped: while the block runs, a profile hook adds to `tripped` the name of every answer (as `arm`
    finds them) that a submission called, in this thread and in threads it starts. It only records: the
    answer runs, and `check` says "flagged" as the grader would. Under a profiler of the user's own
    (cProfile, %prun) it watches nothing rather than switch that off."""
    if sys.getprofile() is not None or threading.getprofile() is not None:
        yield
        return
    key = (tuple(map(id, functions)), boundary)               # found once: gc.get_objects takes a while
    if key not in _state["watched"]:
        _state["watched"][key] = {f.__code__: f"{f.__module__}.{f.__qualname__}" for f in _targets(functions, boundary)}
    names, _state["boundary"] = _state["watched"][key], boundary

    def hook(frame, event, arg):
        if event == "call" and frame.f_code in names and _by_submission(frame.f_back):
            tripped.append(names[frame.f_code])
    sys.setprofile(hook)
    threading.setprofile(hook)
    try:
        yield
    finally:
        threading.setprofile(None)
        sys.setprofile(None)


def arm(functions, boundary):
    """Swap the code of the answers (`_targets`: `functions` and their modules' functions) for
    tripwires. `boundary`: the code object of the sandbox's function that calls the student's (its
    frame marks "called by the checker, not by the submission")."""
    targets = _targets(functions, boundary)
    for key, f in enumerate(targets):
        original = types.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__, f.__closure__)
        original.__kwdefaults__ = f.__kwdefaults__
        _state["originals"][key] = original
        _state["names"][key] = f"{f.__module__}.{f.__qualname__}"
        source = (f"def tripwire(*args, **kwargs):\n"
                  f"    return __import__('sys').modules[{__name__!r}].trip({key}, args, kwargs)\n")
        namespace = {}
        exec(compile(source, f.__code__.co_filename, "exec"), namespace)
        names = {k: getattr(f.__code__, k) for k in ("co_name", "co_qualname") if hasattr(f.__code__, k)}
        f.__code__ = namespace["tripwire"].__code__.replace(**names)      # co_qualname: Python 3.11+
    return len(targets)
