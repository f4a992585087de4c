"""Reading and writing the package's files safely: what a path names is looked at before it is used,
so that a device, a FIFO, a socket or a folder is refused in one line, not read until memory runs
out (/dev/zero), waited on forever (a FIFO), or replaced by a regular file (/dev/null, as root).

    with files.atomic_write("data/train.npz") as f:        # binary; on success it replaces the file
        npz.write(f, arrays)
    with files.open_write("runs/x/log.jsonl") as log:       # text, appended in place ("a", "a+", "w")
        log.write(line)
    with files.open_read("results/runs.csv", "r", newline="") as f:   # text "r" or binary "rb"
        rows = list(csv.reader(f))
    meta = files.loads_json(text)                           # JSON nested at most MAX_JSON_DEPTH deep

Every function takes a path that names a regular file, or (to write) nothing yet, and follows
symbolic links: a link's target is what is read or written, and the link stays a link (`atomic_write`
makes its temporary file in the target's folder). Anything else is `RefusedPath`, a ValueError, so the
commands print one line and exit with status 2 (`oneshot.tools.cli.run`):

    refusing to write '/dev/null': it is a character device, not a regular file; name a file path

Files are opened without blocking and checked again once open (fstat), so a FIFO put in a file's
place after the first look is refused too, not waited on. This module imports no other part of oneshot.
"""
import contextlib
import errno
import json
import os
import re
import secrets
import stat

# Deepest nesting of arrays and objects `loads_json` parses. The package's metadata is at most 4 deep;
# Python's parser raises RecursionError somewhere near 1000, and code walking what it parsed, sooner.
MAX_JSON_DEPTH = 32

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))

# A JSON string (skipped whole, whatever brackets it holds) or one bracket.
_STRING_OR_BRACKET = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)

_UNWRITABLE = (errno.EACCES, errno.EPERM, errno.EROFS)     # a folder that takes no new files


class RefusedPath(ValueError):
    """A path the package will not read or write: it names a folder, a device, a FIFO or a socket, or
    its file cannot be made where it would go. The message names the path and what to name instead."""


class JSONTooDeep(json.JSONDecodeError):
    """JSON nested deeper than `loads_json` parses (a JSONDecodeError, so a reader's handling of
    corrupt JSON covers it); the message gives the depth and where it is passed."""


def kind(mode):
    """What a file of `st_mode` `mode` is, in words: "a regular file", "a folder", "a FIFO (named pipe)"..."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for is_kind, name in _KINDS if is_kind(mode)), f"a special file (mode {oct(mode)})")


def target(path, action="write"):
    """Where reading or writing `path` goes: the path with every symbolic link resolved -> str.
    Raises RefusedPath unless that names a regular file or (to write) nothing yet; FileNotFoundError
    if there is nothing to read."""
    path = os.fspath(path)
    if not path:
        raise RefusedPath(f"cannot {action} '': name a file path")
    real = os.path.realpath(path)
    try:
        mode = os.stat(path if action == "read" else real).st_mode     # reading: say "no such file: path"
    except (FileNotFoundError, NotADirectoryError):
        if action == "read":
            raise
        if os.path.islink(real):                     # realpath stops where links go round in a loop
            raise RefusedPath(f"refusing to write {path!r}: its symbolic links go round in a loop; "
                              f"name a file path") from None
        return real                                  # a new file (its folder is checked on writing)
    except OSError as e:                             # ELOOP, EACCES on a folder on the way, ...
        raise RefusedPath(f"cannot {action} {path!r}: {e.strerror}; name another file path") from None
    if not stat.S_ISREG(mode):
        raise _refusal(action, path, real, mode)
    return real


def _refusal(action, path, real, mode):
    link = f"it links to {real!r}, which is" if os.path.islink(path) else "it is"
    return RefusedPath(f"refusing to {action} {path!r}: {link} {kind(mode)}, not a regular file; name a file path")


@contextlib.contextmanager
def atomic_write(path):
    """Open a temporary file beside `path`'s target for binary writing; when the block ends without
    an error, fsync it and rename it onto the target, else remove it: never half a file there.

    `path` is checked first (`target`): a symbolic link is written through (the link stays, its
    target gets the new file), and anything but a regular file or nothing is RefusedPath, before a
    byte is written. Missing folders are made. A new file gets the usual permissions (0666 less the
    umask), a replaced one keeps its own. A folder that takes no new files is RefusedPath, naming it.
    """
    path = os.fspath(path)
    real = target(path)
    folder = os.path.dirname(real)
    _make_folder(folder, path)
    fd, tmp = _temporary(folder, path, os.path.splitext(real)[1])
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
            with contextlib.suppress(FileNotFoundError):
                os.fchmod(f.fileno(), stat.S_IMODE(os.stat(real).st_mode))   # keep a replaced file's mode
        with contextlib.suppress(FileNotFoundError):                          # still nothing but a file there?
            mode = os.lstat(real).st_mode
            if not stat.S_ISREG(mode):
                raise _refusal("write", path, real, mode)
        os.replace(tmp, real)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)


def _make_folder(folder, path):
    """Make `folder` (and its parents), or raise RefusedPath saying why it cannot be made."""
    try:
        os.makedirs(folder, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        existing = folder
        while not os.path.isdir(existing):
            existing = os.path.dirname(existing)
        raise RefusedPath(f"cannot write {path!r}: {folder!r} cannot be a folder (a file is in the way "
                          f"under {existing!r}); choose another path") from None
    except OSError as e:
        if e.errno not in _UNWRITABLE:
            raise
        raise RefusedPath(f"cannot write {path!r}: the folder {folder!r} cannot be made ({e.strerror}); "
                          f"choose another path") from None


def _temporary(folder, path, suffix):
    """(fd, name) of a new file ".tmp-<random><suffix>" in `folder`, open for writing."""
    while True:
        tmp = os.path.join(folder, f".tmp-{secrets.token_hex(6)}{suffix}")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666), tmp
        except FileExistsError:
            continue
        except OSError as e:
            if e.errno not in _UNWRITABLE:
                raise
            raise RefusedPath(f"cannot write {path!r}: no new files can be made in {folder!r} ({e.strerror}), "
                              f"and a file is written there first and then renamed; choose another path") from None


def open_read(path, mode="rb", **kwargs):
    """`path` opened for reading ("rb", or "r" with open's text arguments: encoding, newline), if it is
    a regular file (or a link to one). Raises FileNotFoundError if there is none, RefusedPath if it is
    anything else, looking before opening and again once open (never waiting on a FIFO)."""
    if mode not in ("r", "rb"):
        raise ValueError(f"open_read reads: mode 'r' or 'rb'; got {mode!r}")
    path = os.fspath(path)                     # a refusal names it as written, not PosixPath('...')
    target(path, "read")
    return open(path, mode, opener=_checked("read", path), **kwargs)


def open_write(path, mode="a", **kwargs):
    """`path` opened to be written in place, not atomically: appended to ("a"; "a+" to read it too) or
    emptied first ("w"); text, with open's text arguments. A missing file is made (not its folder);
    a link is written through; anything but a regular file is RefusedPath, before it is opened."""
    if mode not in ("a", "a+", "w"):
        raise ValueError(f"open_write writes text in place: mode 'a', 'a+' or 'w'; got {mode!r}")
    path = os.fspath(path)
    target(path)
    return open(path, mode, opener=_checked("write", path), **kwargs)


def _checked(action, path):
    """An `opener` for open(): os.open without blocking (a FIFO would block it), then fstat: anything
    but a regular file is closed again and RefusedPath (as is a FIFO or socket put in its place since
    `target` looked, which os.open refuses: ENXIO)."""
    def opener(name, flags):
        try:
            fd = os.open(name, flags | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
        except OSError as e:
            if e.errno != errno.ENXIO:
                raise
            try:                                     # a FIFO without a reader, or a socket
                mode = os.stat(name).st_mode
            except OSError:
                mode = stat.S_IFIFO
            raise _refusal(action, path, os.path.realpath(path), mode) from None
        try:
            mode = os.fstat(fd).st_mode
            if not stat.S_ISREG(mode):
                raise _refusal(action, path, os.path.realpath(path), mode)
            os.set_blocking(fd, True)
        except BaseException:
            os.close(fd)
            raise
        return fd
    return opener


def loads_json(text, max_depth=MAX_JSON_DEPTH):
    """json.loads(text), if its arrays and objects are nested at most `max_depth` deep; else JSONTooDeep
    (a json.JSONDecodeError), found before parsing (deep JSON is a RecursionError in json.loads)."""
    depth = 0
    for match in _STRING_OR_BRACKET.finditer(text):
        bracket = match.group()
        if bracket in "[{":
            depth += 1
            if depth > max_depth:
                raise JSONTooDeep(f"arrays and objects nested deeper than {max_depth}", text, match.start())
        elif bracket in "]}":
            depth -= 1
    return json.loads(text)


def is_json_with(path, keys, limit=1 << 20):
    """May an output that writes a JSON object holding one of `keys` replace the existing file `path`: is
    it empty, or such an object (at most `limit` bytes)? Anything else (a README, a dataset, notes, JSON
    of another kind) is not that output's to overwrite. A device or a FIFO is refused (`open_read`)."""
    with open_read(path) as f:
        head = f.read(limit + 1)
    if not head:
        return True
    if len(head) > limit:
        return False
    try:
        value = loads_json(head.decode("utf-8"))
    except ValueError:                              # not UTF-8 (UnicodeDecodeError), not JSON, too deep
        return False
    return isinstance(value, dict) and any(key in value for key in keys)
