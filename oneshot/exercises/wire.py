"""What travels from a sandboxed submission to the grader: VALUES, never code, as length-prefixed JSON.

The grader judges in its own process and never imports a submission, so nothing a submission sends can
run there: no pickle, only JSON, decoded by `decode` into plain Python and NumPy values:

    None, bool, int, float        as JSON           str      {"str": text}  (at most 1,000 characters)
    tuple, list                   {"tuple": [...]}, {"list": [...]}
    dict                          {"dict": [[key, value], ...]}, keys None, bool, int, float or str
    a numeric array               {"array": "<f8", "shape": [3, 2], "data": base64 of its bytes}
    a NumPy scalar                {"scalar": "<f8", "data": base64}
    anything else                 {"object": "a generator"}: words, read back as `compare.Opaque`

A frame is 4 bytes (big-endian length) then that many bytes of JSON. A submission can write into the
channel too (it runs in the process that writes it); what it writes can only be its own answers,
and `decode` refuses whatever is not one of the forms above with WireError.
"""
import base64
import json
import math
import os
import re
import struct

import numpy as np

from oneshot.exercises.compare import Opaque

MAX_FRAME = 16 << 20          # bytes: an exercise's answers are well under 1 MB
MAX_DEPTH = 24                # nesting of tuples, lists and dicts
_DTYPE = re.compile(r"[<>|][biufc][1-9][0-9]?")


class WireError(ValueError):
    """A frame that is not what the sandbox sends: too long, not JSON, or not a value of the forms above."""


def _words(kind):
    return f"{'an' if kind[:1].lower() in 'aeiou' else 'a'} {kind[:60]}"


def encode(value, depth=0):
    """A value as JSON-ready data (the forms in the module's docstring). Runs in the sandbox."""
    if depth > MAX_DEPTH:
        return {"object": "a value nested too deeply to read"}
    if value is None or type(value) in (bool, int, float):
        return value if not (type(value) is int and abs(value) >= 1 << 63) else float(value)
    if isinstance(value, str):
        return {"str": str(value)[:1000]}
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biufc" or value.dtype.byteorder not in "=<>|":
            return {"object": f"an array of shape {value.shape} and dtype {value.dtype}"}
        return {"array": value.dtype.str, "shape": list(value.shape),
                "data": base64.b64encode(np.ascontiguousarray(value).tobytes()).decode()}
    if isinstance(value, np.generic) and value.dtype.kind in "biufc":
        return {"scalar": value.dtype.str, "data": base64.b64encode(value.tobytes()).decode()}
    if isinstance(value, (tuple, list)):
        return {"tuple" if isinstance(value, tuple) else "list": [encode(v, depth + 1) for v in value]}
    if isinstance(value, dict):
        items = list(value.items())
        if all(k is None or type(k) in (bool, int, float, str) for k, _ in items):
            return {"dict": [[k, encode(v, depth + 1)] for k, v in items]}
    return {"object": _words(type(value).__name__)}


def _dtype(text):
    if not isinstance(text, str) or not _DTYPE.fullmatch(text):
        raise WireError(f"not a numeric dtype: {str(text)[:40]!r}")
    try:
        return np.dtype(text)
    except TypeError:
        raise WireError(f"not a numeric dtype: {text!r}") from None


def _bytes(data, size):
    if not isinstance(data, str) or len(data) > 2 * MAX_FRAME:
        raise WireError("array data is not text")
    try:
        raw = base64.b64decode(data, validate=True)
    except ValueError:
        raise WireError("array data is not base64") from None
    if len(raw) != size:
        raise WireError(f"array data has {len(raw)} bytes; its shape and dtype need {size}")
    return raw


def decode(data, depth=0):
    """The value `encode` made of something; WireError if `data` is anything else. Runs in the grader."""
    if depth > MAX_DEPTH + 1:
        raise WireError("nested too deeply")
    if data is None or type(data) in (bool, int, float):
        return data
    if type(data) is not dict or len(data) not in (1, 2, 3):
        raise WireError(f"not a value: {type(data).__name__}")
    kind = next(iter(data))
    if kind in ("tuple", "list") and len(data) == 1 and type(data[kind]) is list:
        items = [decode(v, depth + 1) for v in data[kind]]
        return tuple(items) if kind == "tuple" else items
    if kind == "dict" and len(data) == 1 and type(data[kind]) is list:
        pairs = data[kind]
        if not all(type(p) is list and len(p) == 2 and (p[0] is None or type(p[0]) in (bool, int, float, str))
                   for p in pairs):
            raise WireError("a dict's items must be [key, value] pairs with simple keys")
        return {k: decode(v, depth + 1) for k, v in pairs}
    if kind in ("str", "object") and len(data) == 1 and type(data[kind]) is str:
        return data[kind][:1000] if kind == "str" else Opaque(clean(data[kind], 120))
    if kind == "array" and set(data) == {"array", "shape", "data"}:
        dtype, shape = _dtype(data["array"]), data["shape"]
        if type(shape) is not list or len(shape) > 32 or not all(type(n) is int and n >= 0 for n in shape):
            raise WireError("an array's shape must be a list of whole numbers >= 0")
        size = math.prod(shape) * dtype.itemsize
        if size > MAX_FRAME:
            raise WireError("an array larger than a frame")
        return np.frombuffer(_bytes(data["data"], size), dtype).reshape(shape).copy()
    if kind == "scalar" and set(data) == {"scalar", "data"}:
        dtype = _dtype(data["scalar"])
        return np.frombuffer(_bytes(data["data"], dtype.itemsize), dtype)[0]
    raise WireError(f"not a value: a dict with keys {sorted(data)[:4]}")


def clean(text, limit=300):
    """Student-made text made safe for a terminal and one line: no control characters (ANSI escapes,
    newlines, carriage returns), at most `limit` characters."""
    text = text if isinstance(text, str) else str(text)
    return "".join(c if c.isprintable() else "?" for c in text[:limit])


# ----- frames --------------------------------------------------------------------------------------

def send(fd, message):
    """Write one frame (a JSON-ready dict) to file descriptor `fd`."""
    payload = json.dumps(message, separators=(",", ":")).encode()
    view = memoryview(struct.pack(">I", len(payload)) + payload)
    while view:
        view = view[os.write(fd, view):]


class Frames:
    """Bytes in, messages (dicts) out: `feed(chunk)` returns the frames the chunk completes; a frame
    longer than MAX_FRAME, or not a JSON object, raises WireError."""

    def __init__(self):
        self.buffer = bytearray()

    def feed(self, chunk):
        self.buffer += chunk
        messages = []
        while len(self.buffer) >= 4:
            (size,) = struct.unpack(">I", self.buffer[:4])
            if size > MAX_FRAME:
                raise WireError(f"a frame of {size} bytes (at most {MAX_FRAME})")
            if len(self.buffer) < 4 + size:
                break
            payload = bytes(self.buffer[4:4 + size])
            del self.buffer[:4 + size]
            try:
                message = json.loads(payload)
            except (ValueError, RecursionError):
                raise WireError("a frame that is not JSON") from None
            if type(message) is not dict:
                raise WireError("a frame that is not a JSON object")
            messages.append(message)
        return messages
