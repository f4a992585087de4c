"""Comparing a result with the expected one, and saying in words where they first differ: which part
of a tuple, which dict key, which array entry (named by its axes), or which shape or type is wrong."""
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Out:
    """The shape of a result, and how a message names it.

    kind: "bool", "number", "array", "tuple" (of `parts`) or "dict" (of arrays, keyed like the expected).
    what: its name in a message ("your loss"); an array's index follows it: "your K[0, 2]".
    axes: names of an array's trailing axes ("frame", "torque"), for messages about shapes.
    labels: per trailing axis, names of its entries (("x", "y"),) or None: "your position p[3, y]".
    """
    kind: str
    what: str = "your result"
    axes: tuple = ()
    labels: tuple = ()
    parts: tuple = ()
    rtol: float = 1e-6
    keep_dtype: bool = False    # an array must come back in the expected dtype (integer arrays always must)


@dataclass(frozen=True)
class Difference:
    message: str
    part: object = None     # the tuple index or dict key where the first difference is; None: the whole


class Opaque:
    """A value that came back from a sandboxed submission as words only (`oneshot.exercises.wire`):
    an object of a type the wire does not carry, e.g. "a generator"."""
    __slots__ = ("words",)

    def __init__(self, words):
        self.words = words

    def __repr__(self):
        return f"<{self.words}>"


def fmt(x):
    return f"{float(x):.6g}"


def fmt_pair(got, want):
    """Two numbers in words, with as many digits as it takes to tell them apart (6 at least)."""
    for digits in range(6, 18):
        g, w = f"{float(got):.{digits}g}", f"{float(want):.{digits}g}"
        if g != w:
            break
    return g, w


def describe(x):
    """A value in a few words: "None", "an array of shape (5,)", "a tuple of 3 items"."""
    if x is None:
        return "None"
    if isinstance(x, Opaque):
        return x.words
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, np.ndarray):
        return f"an array of shape {x.shape}" if x.ndim else f"a 0-d array ({x})"
    if isinstance(x, (tuple, list)):
        return f"a {type(x).__name__} of {len(x)} item{'s' * (len(x) != 1)}"
    if isinstance(x, Mapping):
        return f"a dict with keys {list(x)[:6]}"
    if isinstance(x, (int, float, np.number)):
        return f"the number {fmt(x)}"
    kind = type(x).__name__
    return f"{'an' if kind[0] in 'aeiou' else 'a'} {kind}"


def compare(got, want, out):
    """None if `got` equals `want` (to out.rtol), else the first Difference, in words."""
    return {"bool": _compare_bool, "number": _compare_number, "array": _compare_array,
            "tuple": _compare_tuple, "dict": _compare_dict}[out.kind](got, want, out)


def _compare_bool(got, want, out):
    if not isinstance(got, (bool, np.bool_)):
        return Difference(f"{out.what} is {describe(got)}; expected True or False")
    if bool(got) != bool(want):
        return Difference(f"{out.what} is {bool(got)}; expected {bool(want)}")
    return None


def _compare_number(got, want, out):
    is_number = isinstance(got, (int, float, np.number)) and not isinstance(got, (bool, np.bool_))
    if isinstance(got, np.ndarray) and got.ndim == 0 and got.dtype.kind in "iuf":
        is_number = True
    if not is_number:
        return Difference(f"{out.what} is {describe(got)}; expected a single number")
    g, w = float(got), float(want)
    if np.isclose(g, w, rtol=out.rtol, atol=1e-12):
        return None
    if np.isnan(g):
        return Difference(f"{out.what} is NaN; expected {fmt(w)}")
    relation = ""
    if w != 0 and g != 0:
        ratio = g / w
        if np.isclose(ratio, -1):
            relation = " (the opposite sign)"
        elif abs(ratio - 1) < 1e-3:
            relation = f" (a relative difference of {abs(ratio - 1):.1e}; the checker allows {out.rtol:.0e})"
        else:
            relation = f" ({fmt(ratio)} times the expected value)"
    mine, expected = fmt_pair(g, w)
    return Difference(f"{out.what} is {mine}; expected {expected}{relation}")


def _index(out, index):
    """An array index in words: [2, x] for a (5, 2) position with labels (("x", "y"),)."""
    names = [None] * (len(index) - len(out.labels)) + list(out.labels)[-len(index):] if out.labels else []
    words = []
    for k, i in enumerate(index):
        labels = names[k] if k < len(names) else None
        words.append(str(labels[i]) if labels is not None and i < len(labels) else str(i))
    return "[" + ", ".join(words) + "]"


def _shape_words(got_shape, want_shape, axes):
    if len(got_shape) != len(want_shape):
        return f" ({len(got_shape)} ax{'i' if len(got_shape) == 1 else 'e'}s instead of {len(want_shape)})"
    names = [None] * (len(want_shape) - len(axes)) + list(axes)[-len(want_shape):] if axes else [None] * len(want_shape)
    diffs = [f"{name or f'axis {k}'}: {g} instead of {w}"
             for k, (name, g, w) in enumerate(zip(names, got_shape, want_shape)) if g != w]
    return " (" + "; ".join(diffs) + ")"


def _compare_array(got, want, out):
    want = np.asarray(want)
    try:
        g = np.asarray(got)
    except Exception:
        g = None
    if g is None or g.dtype.kind not in "biuf":
        return Difference(f"{out.what} is {describe(got)}; expected an array of numbers, shape {want.shape}")
    if g.shape != want.shape:
        return Difference(f"{out.what} has shape {g.shape}; expected {want.shape}"
                          f"{_shape_words(g.shape, want.shape, out.axes)}")
    if (want.dtype.kind in "iu" or out.keep_dtype) and g.dtype != want.dtype:
        return Difference(f"{out.what} has dtype {g.dtype}; expected {want.dtype}, the inputs' own dtype")
    g, w = g.astype(float), want.astype(float)
    scale = np.abs(w).max() if w.size else 0.0
    near = lambda a, b: np.isclose(a, b, rtol=out.rtol, atol=out.rtol * scale + 1e-12)
    close = near(g, w)
    if close.all():
        return None
    index = tuple(int(i) for i in np.argwhere(~close)[0])
    relation = ""
    if near(g, -w).all():
        relation = "; it is the expected value with the opposite sign"
    elif (g.ndim >= 2 and g.shape[-1] == g.shape[-2] and near(g, np.swapaxes(w, -1, -2)).all()
          and not near(w, np.swapaxes(w, -1, -2)).all()):      # a symmetric value is its own transpose
        relation = "; it is the transpose of the expected value"
    else:
        nonzero = np.abs(w) > 1e-9 * max(scale, 1e-300)
        ratios = g[nonzero] / w[nonzero]
        if ratios.size and np.allclose(ratios, ratios[0], rtol=1e-6) and np.allclose(g[~nonzero], 0):
            relation = (f"; it is {fmt(ratios[0])} times the expected value everywhere" if abs(ratios[0] - 1) >= 1e-3
                        else f"; a relative difference of {abs(ratios[0] - 1):.1e}, where the checker allows "
                             f"{out.rtol:.0e}")
    wrong = int((~close).sum())
    mine, expected = fmt_pair(g[index], w[index])
    return Difference(f"{out.what}{_index(out, index)} is {mine}; expected {expected}"
                      f" ({wrong} of {close.size} entries differ{relation})")


def _compare_tuple(got, want, out):
    names = ", ".join(p.what.replace("your ", "") for p in out.parts)
    if not isinstance(got, (tuple, list)) or len(got) != len(out.parts):
        return Difference(f"your function returns {describe(got)}; expected a tuple of {len(out.parts)}: ({names})")
    for i, (g, w, part) in enumerate(zip(got, want, out.parts)):
        difference = compare(g, w, part)
        if difference is not None:
            return Difference(difference.message, i)
    return None


def _compare_dict(got, want, out):
    if not isinstance(got, Mapping):
        return Difference(f"{out.what} is {describe(got)}; expected a dict with the keys {list(want)}")
    missing, extra = [k for k in want if k not in got], [k for k in got if k not in want]
    if missing:
        keys = f"key{'s' * (len(missing) > 1)} {missing}"
        return Difference(f"{out.what} lacks the {keys}: return every one of {list(want)}")
    if extra:
        return Difference(f"{out.what} has keys that were not asked for: {extra}")
    for key in want:
        difference = compare(got[key], want[key], _entry(out, key))
        if difference is not None:
            return Difference(difference.message, key)
    return None


def _entry(out, key):
    return Out("array", f"{out.what}['{key}']", rtol=out.rtol)


def part_of(value, out, part):
    """The part of a result where a difference was found, and its Out."""
    if part is None:
        return value, out
    if out.kind == "dict":
        return value[part], _entry(out, part)
    return value[part], out.parts[part]
