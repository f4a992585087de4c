"""Submissions, as a teacher collects them: in a folder, one per student, each a .py file, a notebook
(.ipynb, executed or not), or a folder of them, named for the student.

A notebook is graded as its code: `notebook_code` turns its code cells into one .py file that runs
them in order, like Jupyter's "Run All", going on after a cell that fails (a scratch cell, or a stub
left unwritten); the file records which cells failed, and the grade says so when it finds a function
missing. Lines that are not Python are left out: shell commands (`!pip install ...`) and line magics
(`%matplotlib inline`) become `pass`; a cell that starts with a cell magic (`%%bash`) is left out,
except `%%time`, `%%timeit` and `%%capture`, whose Python is kept. No Jupyter is needed: the notebook
is read with the json module (nbformat 4, or 3).

`working_copy` copies a submission (its regular files only: no symbolic links, devices or FIFOs)
into a fresh folder, where it runs: it never runs where it was handed in.
"""
import json
import os
import shutil
import stat
from pathlib import Path

MAX_BYTES = 50 << 20              # a submission (a notebook with its outputs, or a folder) may hold this much
KEPT_CELL_MAGICS = ("time", "timeit", "capture")
SUFFIXES = (".py", ".ipynb")      # a submission's files


class SubmissionError(ValueError):
    """A submission that cannot be used: missing, not Python or a notebook, or malformed."""


def _regular(path):
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def _folder(path):
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def _code_files(folder):
    return sorted(p for p in Path(folder).iterdir() if p.suffix in SUFFIXES and _regular(p))


def is_submission(path):
    """A .py file, a notebook, or a folder holding either (not a link to one: it could point anywhere)."""
    path = Path(path)
    if _regular(path):
        return path.suffix in SUFFIXES
    return _folder(path) and bool(_code_files(path))


def submissions(folder):
    """The submissions in `folder`, in name order (names starting with "." or "_" are not submissions)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise SubmissionError(f"{folder} is a file, not a folder of submissions: grade the folder that holds it, "
                              f"or check one exercise in it with `python -m oneshot.exercises check N --file {folder}`")
    if not folder.is_dir():
        raise SubmissionError(f"no such folder: {folder}")
    found = sorted(p for p in folder.iterdir() if not p.name.startswith((".", "_")) and is_submission(p))
    if not found:
        raise SubmissionError(f"{folder} holds no submissions (.py files, notebooks, or folders of them)")
    return found


def passed_over(folder):
    """[(name, why), ...]: what in `folder` is named like a submission (a .py file, a notebook, or a link
    to a folder) but is not one `submissions` takes: a symbolic link, a FIFO, a device or a socket, which
    are never followed or read. For the grader to say so."""
    passed = []
    for p in sorted(Path(folder).iterdir()):
        if p.name.startswith((".", "_")) or is_submission(p) or _folder(p):
            continue
        if p.is_symlink() and (p.suffix in SUFFIXES or p.is_dir()):
            passed.append((p.name, "a symbolic link"))
        elif p.suffix in SUFFIXES and not p.is_symlink():
            passed.append((p.name, "a FIFO, a device or a socket, not a file"))
    return passed


def notebook_cells(path):
    """[(cell number, its code), ...] of a notebook's code cells, numbered from 1 among all its cells;
    shell and magic lines are turned into `pass` (see the module's docstring)."""
    path = Path(path)
    if os.path.getsize(path) > MAX_BYTES:
        raise SubmissionError(f"{path.name} is larger than {MAX_BYTES >> 20} MB")
    try:
        with open(path, encoding="utf-8") as f:
            notebook = json.load(f)
    except (ValueError, RecursionError) as e:
        raise SubmissionError(f"{path.name} is not a notebook: {type(e).__name__}: {str(e)[:100]}") from None
    cells = notebook.get("cells") if isinstance(notebook, dict) else None
    if cells is None and isinstance(notebook, dict) and notebook.get("worksheets"):      # nbformat 3
        cells = notebook["worksheets"][0].get("cells") if isinstance(notebook["worksheets"][0], dict) else None
    if not isinstance(cells, list):
        raise SubmissionError(f"{path.name} is not a notebook: it has no list of cells")
    code = []
    for number, cell in enumerate(cells, 1):
        if not isinstance(cell, dict) or cell.get("cell_type") != "code":
            continue
        source = cell.get("source", cell.get("input", ""))
        source = "".join(source) if isinstance(source, list) and all(isinstance(s, str) for s in source) else source
        if not isinstance(source, str):
            raise SubmissionError(f"{path.name}: cell {number}'s source is not text")
        source = python_of(source)
        if source is not None:
            code.append((number, source))
    return code


def python_of(source):
    """A cell's Python: shell (!) and line-magic (%) lines become `pass`; None for a cell whose cell magic
    makes it another language (%%bash, %%html); %%time, %%timeit and %%capture are dropped, their body kept."""
    lines = source.splitlines()
    first = next((line.strip() for line in lines if line.strip()), "")
    if first.startswith("%%"):
        if first[2:].split(" ")[0] not in KEPT_CELL_MAGICS:
            return None
        lines = lines[[line.strip() for line in lines].index(first) + 1:]
    kept = []
    for line in lines:
        body = line.lstrip()
        kept.append(line[:len(line) - len(body)] + "pass" if body.startswith(("!", "%")) else line)
    return "\n".join(kept) + "\n"


def notebook_code(path):
    """The .py text that runs a notebook's code cells as the module's docstring says, recording each
    failure in `__notebook_errors__` as (cell number, exception)."""
    name = Path(path).name
    calls = "".join(f"__cell({number}, {code!r})\n" for number, code in notebook_cells(path))
    return (f'"""The code cells of {name!r}, in order, each going on after one that fails."""\n'
            f"__notebook_errors__ = []\n\n\n"
            f"def __cell(number, code):\n"
            f"    try:\n"
            f"        exec(compile(code, {name + ', cell '!r} + str(number), 'exec'), globals())\n"
            f"    except BaseException as error:\n"
            f"        __notebook_errors__.append((number, error))\n\n\n" + calls)


def working_copy(path, into):
    """Copy submission `path` into the empty folder `into`: its .py files as they are, its notebooks as
    `<name>.ipynb.py` (`notebook_code`), and a folder's other regular files. Returns the .py files to
    load, in order. Raises SubmissionError for a submission too large or not readable."""
    path, into = Path(path), Path(into)
    sources = [path] if _regular(path) else _code_files(path)
    if _folder(path):
        total = 0
        for folder, names, files in os.walk(path):                  # os.walk does not follow links
            for name in files:
                source = Path(folder) / name
                if not _regular(source) or source.suffix == ".ipynb":
                    continue
                total += os.lstat(source).st_size
                if total > MAX_BYTES:
                    raise SubmissionError(f"{path.name} holds more than {MAX_BYTES >> 20} MB")
                target = into / source.relative_to(path)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, target)
    loaded = []
    for source in sources:
        if source.suffix == ".ipynb":
            target = into / (source.name + ".py")
            target.write_text(notebook_code(source), encoding="utf-8")
        else:
            target = into / source.name
            if not target.exists():
                if os.path.getsize(source) > MAX_BYTES:
                    raise SubmissionError(f"{source.name} is larger than {MAX_BYTES >> 20} MB")
                shutil.copyfile(source, target)
        loaded.append(str(target))
    return loaded
