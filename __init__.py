"""Not the package: it is in oneshot/. This file lets a clone of the repository named `oneshot` work from
its parent folder with an editable install (`pip install -e .`): there, Python finds the clone itself, a
folder named oneshot, before the installed package, and would take it (its data/ and results/ folders
too) for the package. Found this way, it hands over to the real package in oneshot/oneshot/."""
import os

__path__ = [os.path.join(os.path.dirname(os.path.abspath(__file__)), "oneshot")]
with open(os.path.join(__path__[0], "__init__.py")) as _f:
    exec(compile(_f.read(), os.path.join(__path__[0], "__init__.py"), "exec"))
