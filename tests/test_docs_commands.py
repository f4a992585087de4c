"""Every `python -m oneshot.X ...` command written for users (the README, docs/, the notebooks, the
package's docstrings and messages) names a command that exists and only flags it accepts: a renamed
flag or subcommand otherwise leaves the docs quietly wrong. The flags are read from the commands' own
parsers (`cli.Parser`), not listed here.
"""
import argparse
import glob
import importlib
import json
import os
import re

import pytest

from oneshot.tools import cli

ROOT = os.path.join(os.path.dirname(__file__), "..")
COMMANDS = ("oneshot.collect", "oneshot.demo", "oneshot.evaluate", "oneshot.train", "oneshot.benchmark",
            "oneshot.experiments", "oneshot.exercises")
# a command runs to the end of its line, a backtick, a pipe, a `;`, a comment, a closing bracket or quote
WRITTEN = re.compile(r"python3? -m (oneshot(?:\.\w+)*)([^\n`|;#)\"'\\]*)")


class _Parsed(Exception):
    def __init__(self, parser):
        self.parser = parser


def _grammar(module):
    """{subcommand or None: {option string: its choices or None}} of `module`'s parser, read by running
    its main() up to its parse_args (which raises here, before any work)."""
    def capture(self, *args, **kwargs):
        raise _Parsed(self)
    main = importlib.import_module(module + ".__main__" if module in ("oneshot.benchmark", "oneshot.experiments",
                                                                      "oneshot.exercises") else module).main
    original, cli.Parser.parse_args = cli.Parser.parse_args, capture
    try:
        main([])
    except _Parsed as parsed:
        parser = parsed.parser
    finally:
        cli.Parser.parse_args = original
    options = lambda p: {s: a.choices for a in p._actions for s in a.option_strings}
    grammar = {None: options(parser)}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            grammar.update({name: {**grammar[None], **options(sub)} for name, sub in action.choices.items()})
    return grammar


def _unwrap(markdown):
    """`markdown` with each inline code span that the prose wraps over lines put back on one line
    (fenced blocks, one command a line, are kept)."""
    parts = re.split(r"(```.*?```)", markdown, flags=re.S)
    return "".join(part if part.startswith("```") else
                   re.sub(r"`[^`]+`", lambda m: m.group(0).replace("\n", " "), part) for part in parts)


def written_commands():
    """(where, module, words) of every command written in the README, docs/, notebooks and package."""
    texts = [os.path.join(ROOT, "README.md"), *glob.glob(os.path.join(ROOT, "docs", "*.md")),
             *glob.glob(os.path.join(ROOT, "oneshot", "**", "*.py"), recursive=True)]
    found = []
    for path in texts:
        with open(path, encoding="utf-8") as f:
            found.append((path, f.read()))
    found = [(path, _unwrap(text) if path.endswith(".md") else text) for path, text in found]
    for path in glob.glob(os.path.join(ROOT, "notebooks", "**", "*.ipynb"), recursive=True):
        with open(path, encoding="utf-8") as f:
            found.append((path, "\n".join(_unwrap("".join(c["source"])) if c["cell_type"] == "markdown"
                                           else "".join(c["source"]) for c in json.load(f)["cells"])))
    return [(f"{os.path.relpath(path, ROOT)}: python -m {m.group(1)}{m.group(2)}", m.group(1), m.group(2).split())
            for path, text in found for m in WRITTEN.finditer(text)]


def check(module, words, grammars):
    """The one-line problem with a written command, or None."""
    if module.split(".")[-1].isupper():             # a placeholder: python -m oneshot.COMMAND
        return None
    if module not in grammars:
        return f"no command {module} (the commands: {', '.join(COMMANDS)})"
    grammar = grammars[module]
    sub = None
    if len(grammar) > 1 and words and not words[0].startswith(("-", "[")):
        sub = words[0].strip("{}.,")
        if sub not in grammar and not sub.isupper() and "," not in words[0]:   # a placeholder: WHAT, {a,b}
            return f"no subcommand {sub!r} (it has {', '.join(sorted(k for k in grammar if k))})"
    known = grammar.get(sub, grammar[None])
    for word, value in zip(words, [*words[1:], ""]):
        flag = word.strip("[](){},.:").split("=")[0]
        if flag.startswith("--") and flag not in known and flag.strip("-"):
            return f"no flag {flag} in {module}{' ' + sub if sub else ''}"
        value = word.split("=", 1)[1] if "=" in word else value.strip("[](),.:")
        choices = known.get(flag)
        placeholder = value.isupper() or "{" in value or "<" in value                 # P, {args.profile}, <name>
        if choices and value and not value.startswith("-") and not placeholder and value not in choices:
            return f"{flag} {value}: not one of {', '.join(map(str, choices))}"
    return None


@pytest.fixture(scope="module")
def grammars():
    """Every command's grammar, and `python -m oneshot`'s: it takes no flag (it names the commands)."""
    return {"oneshot": {None: {}}, **{module: _grammar(module) for module in COMMANDS}}


def test_every_written_command_exists_with_its_flags(grammars):
    commands = written_commands()
    assert len(commands) > 100                        # the README, docs and notebooks are read
    wrong = [f"{where}\n    {problem}" for where, module, words in commands
             if (problem := check(module, words, grammars))]
    assert not wrong, "\n".join(wrong)


def test_the_check_finds_wrong_commands(grammars):
    """The checker against wrong answers as well as right ones."""
    ok = lambda line: check(*line.split(" ", 1)[0:1], line.split()[1:], grammars) is None
    assert ok("oneshot.evaluate CKPT --split test --trials 20 --unadapted")
    assert ok("oneshot.experiments fig2 --profile ablation --lines L --seeds S")
    assert ok("oneshot.benchmark maml --profile literal [--peer torch]")
    assert ok("oneshot.exercises grade DIR --csv F")
    assert not ok("oneshot.evaluate CKPT --split test --trails 20")            # misspelt
    assert not ok("oneshot.experiments fig3 --profile paper")                  # no such subcommand
    assert not ok("oneshot.experiments ship --profile ablation --lines L")     # fig2's flag, not ship's
    assert not ok("oneshot.benchmark expert --peer torch")                     # maml's flag
    assert not ok("oneshot.evaluation CKPT")                                   # no such command
    assert ok("oneshot.COMMAND --help") and ok("oneshot") and not ok("oneshot --profile default")
    assert ok("oneshot.train --profile literal") and ok("oneshot.train --profile P")      # P: a placeholder
    assert not ok("oneshot.train --profile litteral") and not ok("oneshot.train --profile=litteral")
    assert "--split test --trials 20" in _unwrap("the `python -m oneshot.evaluate CKPT --split\ntest --trials 20` row")
    assert grammars["oneshot.train"][None].keys() >= {"--profile", "--seed", "--run"}


def test_the_readme_collects_the_test_data_each_shipped_policy_is_scored_on():
    """The README's results name the collect command before each shipped policy's evaluation: the one
    that `evaluate` would print for the test data its checkpoint records (a fresh clone has no data)."""
    from oneshot.training import checkpoint, run_data
    readme = _unwrap(open(os.path.join(ROOT, "README.md")).read())
    for name in ("mil_default.npz", "mil_every_parameter.npz"):
        cfg = checkpoint.load(os.path.join(ROOT, "oneshot", "pretrained", name))["config"]
        row = next(line for line in readme.splitlines() if f"oneshot/pretrained/{name} --split test" in line)
        assert f"`{run_data.collect_command(cfg, 'test')}`, then `python -m oneshot.evaluate" in row, name
