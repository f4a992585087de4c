"""Every ```python block of the README and docs/*.md runs as written, as a user pastes it: alone, in a
fresh namespace, from the repository root, on a fresh clone (the shipped policy, no trained run or
collected dataset), without writing into the repository. A failure names the page and its line.
Blocks in other languages (```bash, plain ```) are not run; a block that imports Gymnasium (the
optional extra) is skipped without it, as tests/test_gym.py is.
"""
import glob
import os
import re
import tempfile

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```", re.S | re.M)


def python_blocks():
    """(page, index on the page, first line of the code in the page, code) of every ```python block."""
    found = []
    for path in [os.path.join(ROOT, "README.md"), *sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))]:
        with open(path, encoding="utf-8") as f:
            text = f.read()
        page = os.path.relpath(path, ROOT)
        for index, m in enumerate(BLOCK.finditer(text)):
            found.append((page, index, text.count("\n", 0, m.start(1)) + 1, m.group(1)))
    return found


BLOCKS = python_blocks()


def _repository_files():
    """Every file and folder of the repository but caches and git's own."""
    skip = {".git", "__pycache__", ".pytest_cache"}
    return {os.path.join(folder, name) for folder, dirs, files in os.walk(ROOT)
            if not skip.intersection(folder.split(os.sep)) for name in dirs + files}


@pytest.mark.parametrize("page, index, line, code", [pytest.param(*b, id=f"{b[0]}[{b[1]}]") for b in BLOCKS])
def test_python_block_runs_as_written(page, index, line, code, monkeypatch, tmp_path):
    if re.search(r"^\s*import gymnasium", code, re.M):
        pytest.importorskip("gymnasium")
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))      # a block's temporary files go here
    before = _repository_files()
    # padded so that a traceback gives the line in the page (and shows it: the path is relative to ROOT)
    exec(compile("\n" * (line - 1) + code, page, "exec"), {"__name__": "__main__"})
    assert _repository_files() == before, f"{page}, block {index} wrote into the repository"


def test_the_blocks_are_found():
    """The finder reads every page: 7 blocks when this test was written, on world, expert, maml,
    imitation and training."""
    assert len(BLOCKS) >= 7
    assert {page for page, *_ in BLOCKS} >= {os.path.join("docs", f"{p}.md") for p in
                                             ("world", "expert", "maml", "imitation", "training")}
