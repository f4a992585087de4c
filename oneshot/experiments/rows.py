"""The rows of a sweep: one run (`RunSpec`), its runs.csv row (`row_of`), and runs.csv itself, written
atomically and read without trust (`read_rows` names a damaged line)."""
import csv
import io
import json
import os
from dataclasses import dataclass

from oneshot.tools.files import atomic_write, open_read
from oneshot.training.scoring import wilson_interval


# runs.csv, in this column order. `notes`: whatever else run_fn returned, as compact JSON.
COLUMNS = ("method", "size", "colours", "demos_per_colour", "seed", "iterations", "wall_seconds",
           "successes", "trials", "rate", "ci_low", "ci_high", "notes")
_INT_COLUMNS = ("size", "colours", "demos_per_colour", "seed", "iterations", "successes", "trials")
_FLOAT_COLUMNS = ("wall_seconds", "rate", "ci_low", "ci_high")
ROW_FILE = "row.json"                          # in a run's work folder: the row it produced



@dataclass(frozen=True)
class RunSpec:
    """One run: `method` meta-trained for `iterations` meta-iterations on `colours` training colours x
    `demos` demos per colour, with seed `seed`."""
    method: str
    colours: int
    demos: int
    seed: int
    iterations: int

    def __post_init__(self):
        for name in ("colours", "demos"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"{name} must be an int >= 1; got {getattr(self, name)!r}")
        for name in ("seed", "iterations"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be an int >= 0; got {getattr(self, name)!r}")

    @property
    def size(self):
        """Meta-training demonstrations: colours x demos per colour."""
        return self.colours * self.demos

    @property
    def run_id(self):
        """A stable, filesystem-safe name, e.g. "lstm_c72_d12_s1_i6000": the run's work folder."""
        return f"{self.method}_c{self.colours}_d{self.demos}_s{self.seed}_i{self.iterations}"


def row_of(spec, result, wall_seconds):
    """The runs.csv row (a dict over COLUMNS) of a finished run, from run_fn's result dict."""
    if not isinstance(result, dict) or "successes" not in result or "trials" not in result:
        raise ValueError(f"run_fn must return a dict with 'successes' and 'trials'; got {result!r}")
    successes, trials = int(result["successes"]), int(result["trials"])
    if not 0 <= successes <= trials or trials < 1:
        raise ValueError(f"run_fn returned {successes} successes in {trials} trials "
                         f"(need 0 <= successes <= trials, trials >= 1)")
    clash = sorted(set(result) & set(COLUMNS) - {"successes", "trials", "wall_seconds"})
    if clash:
        raise ValueError(f"run_fn returned {clash}: the sweep fills those columns itself")
    extra = {k: v for k, v in result.items() if k not in COLUMNS}
    lo, hi = wilson_interval(successes, trials)
    return {"method": spec.method, "size": spec.size, "colours": spec.colours, "demos_per_colour": spec.demos,
            "seed": spec.seed, "iterations": spec.iterations,
            "wall_seconds": round(float(result.get("wall_seconds", wall_seconds)), 2),
            "successes": successes, "trials": trials, "rate": round(successes / trials, 4),
            "ci_low": round(lo, 4), "ci_high": round(hi, 4),
            "notes": json.dumps(extra, sort_keys=True, separators=(",", ":"),
                                default=lambda x: x.item() if hasattr(x, "item") else str(x))}


def row_id(row):
    """The run_id of a runs.csv row."""
    return RunSpec(row["method"], row["colours"], row["demos_per_colour"], row["seed"], row["iterations"]).run_id


def read_rows(path, fix=None):
    """The rows of a runs.csv (typed: ints, floats, notes as its JSON string); [] if there is none.
    A damaged file (another header, a cut or bogus row, successes outside 0..trials, notes that are not
    a whole JSON object) raises ValueError naming the file and the line, and what to do: `fix`, or for
    a sweep's own file, how to start it afresh or run that line's run again."""
    if not os.path.exists(path):
        return []
    end = 0                                    # the last line read of the last whole row
    with open_read(path, "r", newline="") as f:
        try:
            text = f.read()
            reader = csv.DictReader(io.StringIO(text, newline=""))
            if not reader.fieldnames:
                raise ValueError(f"{path} is empty (not even runs.csv's header); "
                                 f"{fix or 'delete it to start the sweep afresh'}")
            if tuple(reader.fieldnames) != COLUMNS:
                raise ValueError(f"{path}: columns {reader.fieldnames} are not runs.csv's {list(COLUMNS)}; "
                                 f"{fix or 'move the file away to start the sweep afresh'}")
            rows, end = [], reader.line_num
            for row in reader:                 # a row's lines: more than one if a quote runs on
                rows.append(((end + 1, reader.line_num), row))
                end = reader.line_num
        except UnicodeDecodeError:
            raise ValueError(f"{path} is not a runs.csv (it is not text); "
                             f"{fix or 'move the file away to start the sweep afresh'}") from None
        except csv.Error as e:                 # e.g. a quote that runs on past the field size limit
            advice = fix or f"delete line {end + 1} (its run is then done again) or move the file away"
            raise ValueError(f"{path}, from line {end + 1}: not a runs.csv row ({e}; a quote opened there may "
                             f"run on); {advice}") from None
    for line, row in rows:
        try:
            if None in row or None in row.values():     # DictReader: extra fields under None, missing ones None
                fields = len(COLUMNS) + len(row[None]) if None in row else sum(v is not None for v in row.values())
                raise ValueError(f"it has {fields} fields, not {len(COLUMNS)}")
            row.update({k: int(row[k]) for k in _INT_COLUMNS})
            row.update({k: float(row[k]) for k in _FLOAT_COLUMNS})
            if not 0 <= row["successes"] <= row["trials"] or row["trials"] < 1:
                raise ValueError(f"{row['successes']} successes in {row['trials']} trials")
            if min(row["colours"], row["demos_per_colour"]) < 1 or min(row["seed"], row["iterations"]) < 0:
                raise ValueError(f"{row['colours']} colours x {row['demos_per_colour']} demos, seed {row['seed']}, "
                                 f"{row['iterations']} iterations")
            if row["size"] != row["colours"] * row["demos_per_colour"]:
                raise ValueError(f"size {row['size']} is not {row['colours']} colours x {row['demos_per_colour']} demos")
            notes = json.loads(row["notes"])
            if not isinstance(notes, dict):
                raise ValueError("its notes are not a JSON object")
            if "per_colour" in notes:
                _check_per_colour(notes["per_colour"], row["successes"], row["trials"])
            row_id(row)
        except (ValueError, TypeError) as e:                 # the row's lines, but empty ones (csv skips them)
            lines = io.StringIO(text, newline="").readlines()   # split as csv splits them
            line = [n for n in range(line[0], line[1] + 1) if lines[n - 1].rstrip("\r\n")]
            where = (f"line {line[0]}" if len(line) == 1 else
                     f"lines {line[0]}-{line[-1]} (one row: a quote opened on line {line[0]} runs on)")
            advice = fix or f"delete line {line[0]} (its run is then done again) or move the file away"
            raise ValueError(f"{path}, {where}: not a runs.csv row ({e}); {advice}") from None
    return [row for _, row in rows]


def _check_per_colour(counts, successes, trials):
    """Raise ValueError unless `counts` (a row's notes' per_colour: {colour index: successes}, what
    `stats.counts` pairs over colours) shares the row's trials equally among its colours, each colour's
    successes within its trials, and sums to the row's successes."""
    if not (isinstance(counts, dict) and counts and all(k.isdecimal() and k == str(int(k)) for k in counts)
            and all(type(v) is int for v in counts.values())):
        raise ValueError("its notes' per_colour is not {colour: successes}, whole numbers")
    each, rest = divmod(trials, len(counts))
    wrong = [f"{v} on colour {k}" for k, v in counts.items() if not 0 <= v <= each]
    if rest or wrong or sum(counts.values()) != successes:
        raise ValueError(f"its notes' per_colour ({len(counts)} colours, {sum(counts.values())} successes"
                         f"{': ' + ', '.join(wrong[:3]) if wrong else ''}) does not fit its {successes} successes "
                         f"in {trials} trials, {trials / len(counts):g} a colour")


def row_order(row):
    """The order of runs.csv: (method, size, seed, iterations)."""
    return row["method"], row["size"], row["seed"], row["iterations"]


def write_rows(rows, path):
    """Write runs.csv atomically, sorted by `row_order`: never half a file at `path`."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(sorted(rows, key=row_order))
    with atomic_write(path) as f:
        f.write(text.getvalue().encode("utf-8"))
