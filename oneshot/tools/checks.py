"""Checks of plain values that every part of the package shares, each raising one ValueError that names
the value and says what to pass: a whole number (a Python or NumPy int, not a bool, which NumPy reads as
0 or 1, nor a float) and a finite real number (not a bool or a string). Both return a Python int or
float, as JSON saves it.

    size = whole_number("image_size", size, "pass the image's side in pixels, e.g. 32")
"""
import math
import numbers

import numpy as np


def whole_number(name, value, fix):
    """`value` as an int if it is a Python or NumPy integer; else ValueError naming `name` and `fix`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int; got {value!r} ({type(value).__name__}); {fix}")
    return int(value)


def real_number(name, value, fix):
    """`value` as a float if it is a finite real number (a Python or NumPy int or float); else ValueError
    naming `name` and `fix`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number; got {value!r}; {fix}")
    return float(value)
