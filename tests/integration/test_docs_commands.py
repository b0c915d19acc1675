"""Every ``snac-gym`` command line that README.md and docs/*.md show parses with today's options.

A reader copies them; an option renamed or removed would fail in their shell and in no test, since the pages' Python
blocks are what tests/integration/test_docs.py runs. Each line is parsed by the command itself (typer's parser: the
option names, their types and choices), not run. Lines with a placeholder for the reader to fill in (``--seed S``,
``OUT/...``, ``[--param ...]``) are left out, and so is a path the reader will have made (``snac-gym plot runs/demo``).
"""

from __future__ import annotations

import functools
import re
import shlex
from pathlib import Path
from typing import Any

import pytest
import typer

from snac_gym.apps.cli import app

ROOT = Path(__file__).resolve().parents[2]
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: A command line in a code span, or a line of a fenced block (continuation lines joined).
SPAN = re.compile(r"`(snac-gym [^`]+)`")
#: The same in Python source: a message's or a docstring's ``snac-gym ...`` (one or two backticks).
CODE = re.compile(r"`+(snac-gym [^`]+)`+")
FENCED = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
IN_LINE = re.compile(r"(?:^|&& |\$ |/|\s)(snac-gym .*)")
#: Where a shell line's command ends.
ENDS = {";", "&&", "||", "|", "&", ">", ">>", "<", "(", ")"}
#: What the reader fills in: an upper-case word (OUT, S, TASK_SPACE), an optional part or an alternative.
PLACEHOLDER = re.compile(r"(^|[/=_])[A-Z][A-Z_]*([/._:]|$)|[\[\]<>|…]|\.\.\.|/--")


def words(line: str) -> list[str]:
    """The words of the command that ``line`` starts with, as the shell splits them (up to a ``;``, ``&&``, a pipe, a
    redirection or a comment)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";&<>()")  # a | inside a word: an alternative
    lexer.whitespace_split = True
    found = []
    for word in lexer:
        if word in ENDS or word.startswith(("2>", "1>")):
            break
        found.append(word)
    return found


def commands(text: str) -> list[str]:
    """The ``snac-gym ...`` command lines of a page's text, in order, each as the shell would run it."""
    found = SPAN.findall(text)
    for block in FENCED.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            found += IN_LINE.findall(line)
    return [shlex.join(words(line)) for line in found]


@functools.cache
def _group() -> Any:
    """The command-line app as click sees it (built once: typer builds it anew on each call)."""
    return typer.main.get_command(app)


def refusal(command: str) -> str | None:
    """Why the command's own parser refuses ``command`` (``None``: it parses, or it holds a placeholder)."""
    words = shlex.split(command)[1:]  # commands() joined them quoted
    group = _group()
    context = group.context_class(group, info_name="snac-gym")
    if not words or words[0].startswith("-") or any(PLACEHOLDER.search(word) or word == "--help" for word in words):
        return None  # the program named, a line to fill in, or a command's help
    found = group.get_command(context, words[0])
    if found is None:
        return f"no command {words[0]!r}"
    if len(words) == 1:
        return None  # the command named in prose
    try:
        found.make_context(words[0], words[1:], parent=context)
    except Exception as exc:  # typer's own copy of click's exceptions
        if type(exc).__name__ == "Exit":  # --help, --version
            return None
        message = exc.format_message() if hasattr(exc, "format_message") else f"{type(exc).__name__}: {exc}"
        if "does not exist" in message:  # a folder of the reader's earlier run
            return None
        if message == f"Option {words[-1]!r} requires an argument.":  # an option named in prose
            return None
        return message
    return None


def test_every_command_a_message_or_docstring_suggests_parses():
    """The commands the package's own lines tell a user to run (an error's remedy, a docstring's example)."""
    shown = []
    for folder in ("snac_gym", "baselines", "evaluation"):
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text()
            # an f-string's field holds a value at run time: "1" parses as a number, a name and a path alike
            found = [re.sub(r"\{[^{}]*\}", "1", c) for c in CODE.findall(text)]
            shown += [(path.relative_to(ROOT).as_posix(), shlex.join(words(c))) for c in found]
    assert len(shown) > 50
    refused = [f"{where}: {c}\n  {why}" for where, c in shown if (why := refusal(c)) is not None]
    assert refused == []


def test_every_command_the_documentation_shows_parses():
    shown = [(path.relative_to(ROOT).as_posix(), c) for path in DOC_FILES for c in commands(path.read_text())]
    checked = [(where, c) for where, c in shown if len(c.split()) > 2 and not PLACEHOLDER.search(c)]
    assert len(checked) > 120  # the pages' commands were found
    refused = [f"{where}: {c}\n  {why}" for where, c in shown if (why := refusal(c)) is not None]
    assert refused == []


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ("`snac-gym evaluate --workers 2 --contollers snac`", "No such option: --contollers"),
        ("```\nsnac-gym demo --task orbit --steps 10\n```\n", None),  # a value the command itself refuses later
        ("```bash\n$ snac-gym bench --steps ten  # a comment\n```\n", "Invalid value for '--steps'"),
        (
            "```\nsnac-gym evaluate --out runs/x \\\n  --samples 5 --no-such-flag\n```\n",
            "No such option: --no-such-flag",
        ),
        ("`snac-gym evalute --out runs/x`", "no command 'evalute'"),
        ("`snac-gym evaluate --seed S --samples 100`", None),  # a placeholder
    ],
)
def test_a_command_the_parser_refuses_is_named(line, why):
    (command,) = commands(line)
    found = refusal(command)
    assert (found is None) if why is None else (why in found), found
