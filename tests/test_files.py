"""Every file the package writes or reads, against paths that name no regular file (issue 30, classes 1
and 2): a device, a FIFO, a socket or a folder is refused in one line and left as it was, never replaced
by a regular file, read until memory runs out, or waited on; a symbolic link is written through to its
target (the link stays), and a target whose folder takes no new files is refused, naming the folder.

The device is a twin of /dev/null made with mknod (as root; else a link to /dev/null); a read-only
folder is made immutable with chattr +i as root (root ignores file modes), else chmod 555. Anything
that could block is guarded by an alarm, and /dev/zero is only read by a child process under a
memory limit."""
import contextlib
import errno
import os
import pathlib
import re
import resource
import signal
import socket
import stat
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from oneshot import collect, evaluate
from oneshot.data import datasets, npz
from oneshot.experiments import fig2, rows as sweep, summary
from oneshot.tools import files, viz
from oneshot.training import checkpoint, run_folder
from test_checkpoint import save_tiny
from test_hostile import refused

ROOT = pathlib.Path(__file__).resolve().parents[1]
TINY = ["--tasks", "2", "--demos", "2", "--horizon", "10", "--image-size", "8", "--workers", "1"]


@pytest.fixture(autouse=True)
def no_hang():
    """Fail, rather than hang, a test whose code waits on a FIFO (as open() of one does)."""
    def alarm(signum, frame):
        raise TimeoutError("blocked for 10 s: something opened a FIFO and waited on it")
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, 10)
    yield
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def keep():
    """What `make` must keep open during a test (a socket's server), closed after it: left to the garbage
    collector, an open socket warns (ResourceWarning) in whichever later test collects it."""
    held = []
    yield held
    for thing in held:
        thing.close()


def make(kind, path, keep):
    """Put a `kind` of thing at `path`: "FIFO", "socket", "character device", "folder", or "link to a
    FIFO". Returns a pattern of what a refusal says it is. `keep`: a list holding what must stay open."""
    if kind == "FIFO":
        os.mkfifo(path)
        return r"is a FIFO \(named pipe\)"
    if kind == "socket":
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        keep.append(server)
        return "is a socket"
    if kind == "character device":
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))      # /dev/null's twin
            return "is a character device"
        except PermissionError:
            os.symlink("/dev/null", path)
            return "links to '/dev/null', which is a character device"
    if kind == "folder":
        os.mkdir(path)
        return "is a folder"
    os.mkfifo(f"{path}.fifo")
    os.symlink(f"{path}.fifo", path)
    return re.escape(f"links to '{path}.fifo', which is a FIFO (named pipe)")


def refusal(action, path, what):
    """The pattern of the one-line refusal to `action` ("read" or "write") `path`, which `what` (make's)."""
    return f"^refusing to {action} {re.escape(repr(str(path)))}: it {what}, not a regular file; name a file path$"


def no_debris(folder):
    assert not [name for name in os.listdir(folder) if name.startswith(".tmp-")]


def mode_of(path):
    return stat.S_IFMT(os.lstat(path).st_mode)


@contextlib.contextmanager
def read_only(folder):
    """`folder` takes no new files while the block runs, even for root."""
    if os.geteuid() == 0:
        if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode != 0:
            pytest.skip("root ignores file modes, and chattr +i cannot make a read-only folder here")
        try:
            yield
        finally:
            subprocess.run(["chattr", "-i", str(folder)], check=True)
    else:
        os.chmod(folder, 0o555)
        try:
            yield
        finally:
            os.chmod(folder, 0o755)


@pytest.fixture(scope="module")
def dataset(tiny_datasets):
    return datasets.load(tiny_datasets[1])


def _row():
    return sweep.row_of(sweep.RunSpec("mil", 2, 2, 0, 1), {"successes": 1, "trials": 2}, 1.0)


# What the package writes, each by the function that writes it: path, dataset -> None.
WRITERS = {
    "dataset": lambda path, data: datasets.save(data, path),
    "checkpoint": lambda path, data: save_tiny(path),
    "runs.csv": lambda path, data: sweep.write_rows([_row()], path),
    "summary.json": lambda path, data: summary.write_summary({"methods": {}, "runs": 0}, path),
    "film strip (PNG)": lambda path, data: viz.save_atomically(Image.new("RGB", (4, 4)), path),
    "animation (GIF)": lambda path, data: viz.save_gif([Image.new("RGB", (4, 4))] * 2, path),
    "log.jsonl (appended)": lambda path, data: run_folder._log_now(path, {"iteration": 1}),
}
KINDS = ["FIFO", "socket", "character device", "folder", "link to a FIFO"]


# --- 1. output paths --------------------------------------------------------------------------------------

@pytest.mark.parametrize("writer", WRITERS)
def test_writing_through_a_link_writes_its_target_and_keeps_the_link(tmp_path, dataset, writer):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir(), there.mkdir()
    name = "out.gif" if "GIF" in writer else "out.png" if "PNG" in writer else "out.npz"
    (there / name).write_bytes(b"old")
    os.symlink(there / name, here / name)
    WRITERS[writer](here / name, dataset)
    assert os.readlink(here / name) == str(there / name)               # still the link it was
    written = (there / name).read_bytes()                              # a log is appended to, the rest replaced
    assert written.startswith(b"old{") if writer.startswith("log") else not written.startswith(b"old")
    assert os.listdir(here) == [name] and os.listdir(there) == [name]   # no temporary file left


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("writer", WRITERS)
def test_writers_refuse_what_is_not_a_regular_file_and_leave_it(tmp_path, dataset, writer, kind, keep):
    path = tmp_path / "out.png"
    what = make(kind, path, keep)
    before = mode_of(path)
    with pytest.raises(ValueError, match=refusal("write", path, what)):
        WRITERS[writer](path, dataset)
    assert mode_of(path) == before
    no_debris(tmp_path)


def test_a_link_into_a_folder_that_takes_no_new_files_is_refused_naming_it(tmp_path, dataset):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir(), there.mkdir()
    (there / "d.npz").write_bytes(b"old")
    os.symlink(there / "d.npz", here / "d.npz")
    with read_only(there):
        with pytest.raises(ValueError, match=f"cannot write '{here / 'd.npz'}': no new files can be made in "
                                             f"'{there}' .*choose another path"):
            datasets.save(dataset, here / "d.npz")
    assert os.readlink(here / "d.npz") == str(there / "d.npz") and (there / "d.npz").read_bytes() == b"old"
    assert os.listdir(here) == ["d.npz"]


def test_a_replaced_file_keeps_its_permissions_and_a_new_one_gets_the_usual(tmp_path, dataset):
    (tmp_path / "private.npz").write_bytes(b"old")
    os.chmod(tmp_path / "private.npz", 0o600)
    datasets.save(dataset, tmp_path / "private.npz")
    datasets.save(dataset, tmp_path / "new.npz")
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(os.stat(tmp_path / "private.npz").st_mode) == 0o600
    assert stat.S_IMODE(os.stat(tmp_path / "new.npz").st_mode) == 0o666 & ~umask


# The command line refuses the same, before any work.

@pytest.mark.parametrize("kind", ["character device", "FIFO", "socket", "link to a FIFO"])
def test_collect_refuses_out_that_is_no_file_before_collecting(capsys, tmp_path, kind, keep):
    path = tmp_path / "d.npz"
    make(kind, path, keep)
    before = mode_of(path)
    line, printed = refused(capsys, collect.main, ["--out", str(path), *TINY])
    assert printed == "" and mode_of(path) == before
    with pytest.raises(ValueError) as writing:
        sweep.write_rows([], path)
    assert line == f"error: argument --out: {writing.value} (see python -m oneshot.collect --help)"   # the same words


def test_evaluate_refuses_a_json_path_that_is_a_fifo_before_any_work(capsys, tmp_path):
    os.mkfifo(tmp_path / "r.json")
    line, printed = refused(capsys, evaluate.main, ["missing.npz", "--json", str(tmp_path / "r.json")])
    assert "argument --json: refusing to write" in line and "a FIFO (named pipe)" in line and printed == ""


def test_is_json_with_accepts_an_empty_file_or_an_object_holding_a_key_and_nothing_else(tmp_path):
    """What an output of JSON may replace: its own kind (an object holding one of its keys, through a
    link too) or an empty file; not a list, an object of another kind, text, bytes that are not UTF-8,
    JSON nested too deep, or a file past the limit (however it begins)."""
    path, link = tmp_path / "f.json", tmp_path / "link.json"
    link.symlink_to(path)
    for content, ours in ((b"", True), (b'{"test": {}}', True), (b'{\n "validation": 1, "x": 2}', True),
                          (b'[{"test": 1}]', False), (b'{"policy": {}}', False), (b"# my notes\n", False),
                          (b'{"test": "\xff"}', False), (b'{"test": ' + b"[" * 40 + b"]" * 40 + b"}", False),
                          (b'{"test": 1', False)):
        path.write_bytes(content)
        assert files.is_json_with(path, ("validation", "test")) is ours, content
        assert files.is_json_with(link, ("validation", "test")) is ours, content
    path.write_bytes(b'{"test": 1}')
    assert files.is_json_with(path, ("test",), limit=11) and not files.is_json_with(path, ("test",), limit=10)


def test_evaluate_json_replaces_only_an_earlier_result_before_any_work(capsys, tmp_path):
    """`--json README.md` replaced the README with JSON (and so a dataset, a script, notes): now a file
    that is not an evaluate result (nor empty) is refused before any data is read, and left."""
    save_tiny(tmp_path / "c.npz")
    for name, content in (("README.md", b"# oneshot\n"), ("data.npz", b"PK\x03\x04"),
                          ("summary.json", b'{"split": "test", "policies": []}')):
        (tmp_path / name).write_bytes(content)
        line, printed = refused(capsys, evaluate.main, [str(tmp_path / "c.npz"), "--validation", "missing.npz",
                                                        "--json", str(tmp_path / name)])
        assert line == (f"error: argument --json {tmp_path / name} exists and is not a result of evaluate --json "
                        f"(this command would replace it); name another file, or move that one aside first "
                        f"(see python -m oneshot.evaluate --help)") and printed == ""
        assert (tmp_path / name).read_bytes() == content


def test_collect_writes_through_a_link_and_refuses_one_into_a_read_only_folder(capsys, tmp_path):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir(), there.mkdir()
    os.symlink(there / "d.npz", here / "d.npz")                    # a link to a file not made yet
    collect.main(["--out", str(here / "d.npz"), *TINY])
    assert os.path.islink(here / "d.npz") and datasets.load(there / "d.npz")["images"].shape[:2] == (2, 2)
    capsys.readouterr()
    with read_only(there):
        line, printed = refused(capsys, collect.main, ["--out", str(here / "d.npz"), *TINY])
    assert f"no new files can be made in '{there}'" in line and printed == ""


# How atomic_write writes: never half a file at the path, whatever happens on the way.

def test_atomic_write_syncs_the_whole_new_file_before_it_takes_the_files_place(tmp_path, monkeypatch):
    """A power cut just after the rename must find the new bytes, not an empty file: the temporary file is
    flushed and fsynced while the old file is still in place."""
    path = tmp_path / "d.npz"
    path.write_bytes(b"old")
    synced, fsync = [], os.fsync

    def watched(fd):
        synced.append((os.fstat(fd).st_size, path.read_bytes()))
        fsync(fd)
    monkeypatch.setattr(os, "fsync", watched)
    with files.atomic_write(path) as f:
        f.write(b"new bytes")
    assert synced == [(9, b"old")] and path.read_bytes() == b"new bytes"


def test_a_fifo_put_in_the_files_place_while_it_is_written_is_refused_and_left(tmp_path):
    path = tmp_path / "d.npz"
    with pytest.raises(files.RefusedPath, match=refusal("write", path, r"is a FIFO \(named pipe\)")):
        with files.atomic_write(path) as f:
            f.write(b"new")
            os.mkfifo(path)                                    # after the first look, before the rename
    assert stat.S_ISFIFO(os.lstat(path).st_mode)
    no_debris(tmp_path)


def test_a_file_in_the_way_of_a_folder_to_make_is_refused_naming_it(tmp_path):
    (tmp_path / "file").write_text("mine")
    path, folder = tmp_path / "file" / "sub" / "d.npz", tmp_path / "file" / "sub"
    says = f"cannot write '{path}': '{folder}' cannot be a folder (a file is in the way under '{tmp_path}'); choose"
    with pytest.raises(files.RefusedPath, match=re.escape(says)):
        with files.atomic_write(path) as f:
            f.write(b"new")
    assert os.listdir(tmp_path) == ["file"] and (tmp_path / "file").read_text() == "mine"


@pytest.mark.parametrize("code", ["EACCES", "EPERM", "EROFS"])
def test_a_folder_that_takes_no_new_files_is_refused_whichever_error_says_so(tmp_path, monkeypatch, code):
    """chmod 555 says EACCES, chattr +i (as root) EPERM, a read-only mount EROFS: `read_only` can make one
    of the first two here, so the temporary file's creation is refused with each."""
    opened = os.open

    def refusing(name, flags, *args, **kwargs):
        if os.path.basename(name).startswith(".tmp-"):
            raise OSError(getattr(errno, code), os.strerror(getattr(errno, code)), name)
        return opened(name, flags, *args, **kwargs)
    monkeypatch.setattr(os, "open", refusing)
    with pytest.raises(files.RefusedPath, match=f"^cannot write '{tmp_path / 'd.npz'}': no new files can be made in "
                                                f"'{tmp_path}' .*; choose another path$"):
        with files.atomic_write(tmp_path / "d.npz") as f:
            f.write(b"new")
    assert os.listdir(tmp_path) == []


# --- 2. input paths ---------------------------------------------------------------------------------------

READERS = {
    "dataset": datasets.load,
    "checkpoint": checkpoint.load,
    "npz archive": npz.read,
    "runs.csv": sweep.read_rows,
    "summary.json": lambda path: fig2.load_results(path.parent),
    "log.jsonl (on resume)": lambda path: run_folder._truncate_log(str(path), 0),
}


@pytest.mark.parametrize("kind", ["FIFO", "character device", "socket", "link to a FIFO"])
@pytest.mark.parametrize("reader", READERS)
def test_readers_refuse_what_is_not_a_regular_file_without_reading_it(tmp_path, reader, kind, keep):
    (tmp_path / "fig2_x").mkdir()
    path = tmp_path / "fig2_x" / "summary.json"
    what = make(kind, path, keep)
    before = mode_of(path)
    with pytest.raises(ValueError, match=refusal("read", path, what)):
        READERS[reader](path)
    assert mode_of(path) == before


@pytest.mark.parametrize("kind", ["FIFO", "socket"])
@pytest.mark.parametrize("action, mode", [("read", "rb"), ("write", "a"), ("write", "w"), ("write", "a+")])
def test_a_fifo_put_in_a_files_place_after_the_first_look_is_refused_once_open(tmp_path, monkeypatch, keep, kind,
                                                                                action, mode):
    """The look before opening passed (a regular file), then a FIFO or a socket took the file's place:
    opened without blocking and refused, not waited on: on fstat, or on os.open's ENXIO ("a" and "w" meet
    no reader at a FIFO; a socket cannot be opened), which was an OSError (exit 1) saying "No such device
    or address", and then called every such thing a FIFO. A pathlib.Path is named as written, not
    PosixPath('...')."""
    path = tmp_path / "log.jsonl"
    path.write_text("")
    look, what = files.target, []

    def then_another_kind(*args):
        real = look(*args)
        os.remove(path)
        what.append(make(kind, path, keep))
        return real
    monkeypatch.setattr(files, "target", then_another_kind)
    signal.setitimer(signal.ITIMER_REAL, 2)                    # no_hang's alarm, sooner
    with pytest.raises(files.RefusedPath) as refused_:
        files.open_read(path, mode) if action == "read" else files.open_write(path, mode)
    assert re.match(refusal(action, path, what[0]), str(refused_.value)), str(refused_.value)
    assert (stat.S_ISFIFO if kind == "FIFO" else stat.S_ISSOCK)(os.lstat(path).st_mode)


def test_reading_through_a_link_to_a_regular_file_still_works(tmp_path, tiny_datasets):
    os.symlink(tiny_datasets[1], tmp_path / "d.npz")
    assert np.array_equal(datasets.load(tmp_path / "d.npz")["images"], datasets.load(tiny_datasets[1])["images"])


@pytest.mark.parametrize("load", ["datasets.load", "checkpoint.load"])
def test_dev_zero_is_refused_in_one_line_without_reading_it(load):
    """What read 22 GB: in a child limited to 2 GB of address space, so that a regression fails, not the machine."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
    code = ("from oneshot.tools import cli; from oneshot.data import datasets; "
            f"from oneshot.training import checkpoint; cli.run(lambda argv: {load}('/dev/zero'))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, preexec_fn=limit,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1"))
    assert done.returncode == 2 and done.stderr == ("error: refusing to read '/dev/zero': it is a character device, "
                                                    "not a regular file; name a file path\n"), done.stderr
