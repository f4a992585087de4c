"""The grade as a gradebook: a CSV (one row per student, as nbgrader's and otter-grader's exports have
it) or JSON, written atomically, for a spreadsheet or an LMS upload.

CSV columns: student (the submission's name without its extension), submission (as handed in:
"alice.ipynb", "carol/"), one `exercise_N` column per assigned exercise (1 correct, 0 not), total,
max_score, flagged (the exercises whose function called the package's own answer, e.g. "5 9"), and
notes (what was not correct, in short: "6 not yet; 7 timed out", or why the code did not load).
A text cell that a spreadsheet would run as a formula (starting with =, +, -, @) gets a leading '.

JSON: {"exercises": [5, 6], "students": [{"student", "submission", "points": {"5": 1, ...},
"verdicts": {"5": "correct", ...}, "total", "max_score", "flagged", "load_error", "notes"}, ...]}.
"""
import csv
import io
import json

from oneshot.tools import files


def _stem(label):
    name = label.rstrip("/")
    return name.rsplit(".", 1)[0] if "." in name and not label.endswith("/") else name


def _short(verdict):
    return str(verdict).split(":", 1)[0].split(" after")[0].split(" (")[0]


def rows(graded, numbers):
    """One dict per submission: the CSV's columns."""
    table = []
    for one in graded:
        row = {"student": _stem(one.label), "submission": one.label}
        row.update({f"exercise_{n}": one.points(n) for n in numbers})
        notes = one.load_error or "; ".join(f"{n} {_short(one.verdicts[n])}" for n in numbers
                                            if one.verdicts.get(n) != "correct")
        row.update(total=one.total, max_score=len(numbers), flagged=" ".join(map(str, one.flagged)), notes=notes)
        table.append(row)
    return table


def _safe(cell):
    return "'" + cell if isinstance(cell, str) and cell[:1] in ("=", "+", "-", "@", "\t", "\r") else cell


def csv_text(graded, numbers):
    out = io.StringIO()
    writer = csv.DictWriter(out, ["student", "submission", *(f"exercise_{n}" for n in numbers), "total",
                                  "max_score", "flagged", "notes"], lineterminator="\n")
    writer.writeheader()
    for row in rows(graded, numbers):
        writer.writerow({k: _safe(v) for k, v in row.items()})
    return out.getvalue()


def json_text(graded, numbers):
    students = [{"student": _stem(g.label), "submission": g.label,
                 "points": {str(n): g.points(n) for n in numbers},
                 "verdicts": {str(n): g.verdicts.get(n) for n in numbers}, "total": g.total,
                 "max_score": len(numbers), "flagged": g.flagged, "load_error": g.load_error, "notes": g.notes}
                for g in graded]
    return json.dumps({"exercises": list(numbers), "students": students}, indent=1) + "\n"


# How each gradebook this module writes begins: an output may replace a file that begins so, never another.
_BEGINS = {"csv": b"student,submission,", "json": b'{\n "exercises": ['}


def is_gradebook(path, kind):
    """May a gradebook of `kind` ("csv" or "json") replace the existing file `path`: is it empty, or did
    this module write it (it begins as `csv_text` or `json_text` does, after the byte-order mark a
    spreadsheet's "CSV UTF-8" adds)? Anything else (a README, a dataset, a notebook) is not ours to
    overwrite. A device or a FIFO is refused (`files.open_read`)."""
    begins = _BEGINS[kind]
    with files.open_read(path) as f:
        head = f.read(len(begins) + 3)
    return not head or head.removeprefix(b"\xef\xbb\xbf").startswith(begins)


def write(path, text):
    """Write `text` (UTF-8) to `path` atomically, through a symbolic link to its target (`files.atomic_write`:
    a regular file or nothing yet; a folder, a device or a FIFO is refused)."""
    with files.atomic_write(path) as f:
        f.write(text.encode("utf-8"))
