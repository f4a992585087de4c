"""What the command-line tools share: argument types that say what they accept, checks made before
any work (a path an output can be written to, memory for what is about to be allocated), and `run`,
which turns the package's errors into one line on stderr and an exit status:

    $ python -m oneshot.collect --out data/x.npz --workers 0
    error: argument --workers: expected a whole number >= 1; got '0' (see python -m oneshot.collect --help)

Exit statuses: 0 done; 2 bad input (an argument, a missing or malformed file); 1 a failure on the
way (training diverged, a worker process died, the disk); 130 interrupted (Ctrl-C).
The commands import this module; it imports no other part of oneshot than `files` (safe reading
and writing).
"""
import argparse
import errno
import math
import os
import re
import signal
import sys
import tempfile

from oneshot import interrupted_while_importing
from oneshot.tools import files

BAD_INPUT = (ValueError, FileNotFoundError, FileExistsError)   # DatasetError, files.RefusedPath are ValueErrors


class Parser(argparse.ArgumentParser):
    """argparse's parser, but an error is one line, `error: argument --flag: ...` (exit status 2),
    not the usage block followed by the message."""

    def error(self, message):
        commands = re.fullmatch(r"the following arguments are required: \{(\w[\w,-]*)\}", message)
        if commands:                              # no subcommand given: name them in words
            *first, last = commands.group(1).split(",")
            message = f"name a command: {', '.join(first)} or {last}" if first else f"name the command {last}"
        sys.stderr.write(f"error: {message} (see {self.prog} --help)\n")
        raise SystemExit(2)


# --- argument types (argparse prefixes their messages with the flag) -------------------------------

def at_least(least, why=""):
    """An argparse type: a whole number >= `least`; `why` is added to the message when it is not."""
    def whole_number(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < least:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {least}{why}; got {text!r}")
        return value
    return whole_number


positive_int = at_least(1)
non_negative_int = at_least(0)


def finite_non_negative_float(text):
    """An argparse type: a finite real number >= 0 (not nan or inf)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0; got {text!r}")
    return value


def _comma_separated(item, what, example):
    """An argparse type: comma-separated values of the argparse type `item`, as a tuple."""
    def parse(text):
        try:
            return tuple(item(x) for x in text.split(","))
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, e.g. {example}; got {text!r}") from None
    return parse


finite_non_negative_floats = _comma_separated(finite_non_negative_float, "finite numbers >= 0", "0.1,0.5,1")
positive_ints = _comma_separated(positive_int, "whole numbers >= 1", "200,200")      # layer widths


TRUE, FALSE = ("true", "1", "yes"), ("false", "0", "no")


def boolean(text):
    """An argparse type: true/1/yes or false/0/no (any case); anything else is an error, not False."""
    if text.strip().lower() in TRUE + FALSE:
        return text.strip().lower() in TRUE
    raise argparse.ArgumentTypeError(f"expected one of {'/'.join(TRUE)} or {'/'.join(FALSE)}; got {text!r}")


def writable_file(path):
    """An argparse type: `path`, if a file can be written there as `files.atomic_write` writes it: it
    names a regular file, a link to one, or nothing yet (not a folder, a device, a FIFO), and the folder
    of the file (a link's target) exists and takes new files, or can be created. Leaves nothing on
    disk, so an unwritable output fails before the work, not after it."""
    if not path:
        raise argparse.ArgumentTypeError("expected a file path; got ''")
    try:
        real = files.target(path)                        # what atomic_write will write
    except files.RefusedPath as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    _check_folder(os.path.dirname(real), path)
    return path


def writable_folder(path):
    """An argparse type: `path`, if files can be written in it: a folder that takes new files, or one
    that can be created. Leaves nothing on disk."""
    if not path:
        raise argparse.ArgumentTypeError("expected a folder path; got ''")
    _check_folder(os.path.abspath(path), path)
    return path


def not_an_input(out, inputs, flag, what="an input of this command"):
    """Raise ValueError if the output path `out` (given with `flag`) is one of the paths `inputs`, or lies
    inside one of them (a folder), links followed: writing it would destroy what the command reads.
    Empty or None inputs are skipped."""
    real = os.path.realpath(out)
    for path in inputs:
        if path and real == os.path.realpath(path):
            raise ValueError(f"{flag} {out} would overwrite {path}, {what}; name another file for {flag}")
        if path and real.startswith(os.path.realpath(path) + os.sep):
            raise ValueError(f"{flag} {out} would write into {path}, {what}; name a file outside it for {flag}")


def replaces_only(out, same_kind, flag, what):
    """Raise ValueError if a file exists at the output path `out` (given with `flag`) and `same_kind(out)`
    is false: an output may replace a file of its own kind (`what`: "a dataset of demonstrations"),
    never another (a trained policy under a dataset's name)."""
    if os.path.exists(out) and not same_kind(out):
        raise ValueError(f"{flag} {out} exists and is not {what} (this command would replace it); name another "
                         f"file, or move that one aside first")


def _check_folder(folder, path):
    """Raise ArgumentTypeError unless `folder` is, or can be created as, a folder that takes new files."""
    existing = folder
    while not os.path.exists(existing):                  # the nearest existing ancestor
        if os.path.lexists(existing):                    # a link that leads nowhere: mkdir would fail on it
            raise argparse.ArgumentTypeError(f"cannot write {path!r}: {existing!r} is a symbolic link to nothing "
                                             f"(or a loop of links); remove it, or choose another path")
        existing = os.path.dirname(existing)
    name_max = os.pathconf(existing, "PC_NAME_MAX") if os.path.isdir(existing) else 255
    too_long = [part for part in os.path.relpath(folder, existing).split(os.sep) if len(os.fsencode(part)) > name_max]
    if too_long or len(os.fsencode(folder)) >= os.pathconf("/", "PC_PATH_MAX"):
        what = f"its name {too_long[0][:20]}... has {len(os.fsencode(too_long[0]))} bytes, more than the {name_max} a name " \
               f"may have here" if too_long else "the path is longer than this system allows"
        raise argparse.ArgumentTypeError(f"cannot write {path!r}: {what}; choose a shorter path")
    if not os.path.isdir(existing):
        raise argparse.ArgumentTypeError(f"cannot write {path!r}: {existing!r} is a file, not a folder; choose "
                                         f"another path")
    try:                                                 # try it: os.access says yes to root on a
        tempfile.TemporaryFile(dir=existing).close()     # read-only file system
    except OSError as e:
        raise argparse.ArgumentTypeError(f"cannot write {path!r}: no new files can be made in {existing!r} "
                                         f"({e.strerror or e}); choose another path") from None


# --- memory ----------------------------------------------------------------------------------------

def available_memory_bytes():
    """Bytes of memory that can be allocated without swapping: /proc/meminfo's MemAvailable (Linux),
    else the free physical pages (os.sysconf), else None (unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024          # the file counts kB
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def dataset_bytes(tasks, demos, horizon, image_size, n_objects):
    """Bytes of a dataset of `oneshot.data.datasets`'s layout in memory: tasks x demos x horizon frames of
    (image_size, image_size, 3) uint8 images, states (6 float32) and torques (2 float32), and per demo
    its objects' colours (int16) and positions (2 float32), target index (int8) and seed (int64)."""
    per_frame = image_size * image_size * 3 + 6 * 4 + 2 * 4
    per_demo = horizon * per_frame + n_objects * (2 + 2 * 4) + 1 + 8
    return tasks * demos * per_demo + tasks * 2


def check_memory(nbytes, what, fix):
    """Raise ValueError("<what> would take <size> ... <fix>") if `nbytes` exceed the available memory."""
    available = available_memory_bytes()
    if available is not None and nbytes > available:
        raise ValueError(f"{what} would take {human_bytes(nbytes)} of memory, and {human_bytes(available)} "
                         f"is available; {fix}")


def human_bytes(n):
    """1234567 -> '1.2 MB' (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 999.5:
            return f"{n:.1f} {unit}" if n < 99.95 else f"{n:.0f} {unit}"
        n /= 1000
    return f"{n:,.0f} PB"


# --- running a command -----------------------------------------------------------------------------

def run(main, argv=None, failures=()):
    """Call a command's `main(argv)` and return what it returns, but turn the package's errors into
    one line on stderr and an exit status (no traceback for what a person can fix):

        2    ValueError (datasets.DatasetError, files.RefusedPath among them), FileNotFoundError, FileExistsError:
             bad input; the message says what and how to fix it
        1    the `failures` types (e.g. loop.TrainingDiverged, shards.ShardError) and other OSError;
             lines after the first of their message (a worker's traceback) are printed after it; a full
             disk (ENOSPC) says so and what to do; MemoryError says to ask for less
        141  stdout's reader went away (a broken pipe, `| head`): nothing is printed
        130  KeyboardInterrupt ("interrupted", or its message: e.g. where training saved its checkpoint);
             a plain kill (SIGTERM) is handled as Ctrl-C, and so is Ctrl-C while the command was still
             importing (`oneshot.interrupted_while_importing`)
    Anything else is a bug, and keeps its traceback.
    """
    if signal.getsignal(signal.SIGINT) is interrupted_while_importing:   # the command's imports are done
        signal.signal(signal.SIGINT, signal.default_int_handler)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return main(argv)
    except KeyboardInterrupt as e:             # its message, if any, says what was saved
        _exit(str(e) or "interrupted", 130)
    except BAD_INPUT as e:
        _exit(" ".join(_lines(e)), 2)
    except BrokenPipeError:                    # its reader went away (`... | head`): stop quietly, as `cat` does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())     # (no flush error at exit)
        raise SystemExit(141)
    except MemoryError:                        # NumPy could not allocate what was asked (a checked size is refused earlier)
        _exit("out of memory: this machine cannot hold what was asked; ask for less (a smaller --meta-batch or "
              "--inner-steps, fewer --workers)", 1)
    except OSError as e:
        if e.errno == errno.ENOSPC and not isinstance(e, failures):   # say what to do, not just the errno
            _exit(f"the disk is full (no space left on device{' for ' + repr(e.filename) if e.filename else ''}); "
                  f"free some space, or write to another disk", 1)
        _exit("\n".join(_lines(e)), 1)
    except failures as e:
        _exit("\n".join(_lines(e)), 1)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _lines(error):
    return [line for line in str(error).strip().splitlines() if line.strip()] or [type(error).__name__]


def _exit(message, status):
    sys.stdout.flush()
    sys.stderr.write(f"error: {message}\n")
    raise SystemExit(status)
