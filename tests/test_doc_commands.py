"""Every ``companion ...`` and ``mavsim ...`` command shown in the user docs names a real
subcommand and only flags its parser accepts.

The commands are read from README.md, mavsim/README.md and docs/*.md (not docs/notes/,
which is dated history): the lines of fenced and indented code blocks, and inline code
spans, that start with ``companion``, ``mavsim``, ``python -m companion.cli`` or
``python -m mavsim`` (also with a path, ``~/venv/bin/companion``, or as a systemd
``ExecStart=``). Lines continued with ``\\`` are joined, comments after `` # ``
dropped, and a command ends at a shell operator (`` | ``, ``&&``, ``;``, ``&``, ``>``).
Optional parts written ``[--flag ...]`` are checked like the rest. Nothing is run: the
parsers are built (``companion.cli.build_parser``, ``mavsim.cli.build_parser``) and each
flag is looked up, exactly (no argparse abbreviations), in its subcommand's options.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from companion.cli import build_parser as companion_parser
from mavsim.cli import build_parser as mavsim_parser

ROOT = Path(__file__).resolve().parent.parent
FENCE = re.compile(r"^\s*(```|~~~)\s*([\w+-]*)")
START = re.compile(r"^(?:\$\s+)?(?:ExecStart=)?(?:python3?\s+-m\s+|\S*/)?(companion\.cli|companion|mavsim)(?=\s|$)(.*)$")
INLINE = re.compile(r"`([^`\n]+)`")
OPERATOR = re.compile(r"\s(?:\|\s|&&|;|&(?:\s|$)|>)")
FLAG = re.compile(r"(?:^|[\s\[|])(--?[A-Za-z][\w-]*)")
#: Code blocks in these languages hold no shell commands (``companion = Companion(...)``).
NOT_SHELL = {"python", "py", "toml", "json", "text"}


def pages() -> list[Path]:
    return [ROOT / "README.md", ROOT / "mavsim" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _code_lines(text: str) -> list[str]:
    """Shell-like lines of fenced and indented code blocks, continuations joined, and inline spans."""
    lines: list[str] = []
    fenced, shell, previous_blank, indented = False, True, True, False
    for line in text.splitlines():
        fence = FENCE.match(line)
        if fence:
            fenced = not fenced
            shell = fence.group(2).lower() not in NOT_SHELL
            continue
        if fenced:
            if shell:
                lines.append(line.strip())
            continue
        indented = line.startswith("    ") and line.strip() != "" and (previous_blank or indented)
        if indented:
            lines.append(line.strip())
        else:
            lines.extend(span.strip() for span in INLINE.findall(line))
        previous_blank = line.strip() == ""
    joined: list[str] = []
    for line in lines:
        if joined and joined[-1].endswith("\\"):
            joined[-1] = joined[-1][:-1].rstrip() + " " + line
        else:
            joined.append(line)
    return joined


def commands() -> list[tuple[str, str, str]]:
    """(page, program, the command's words after the program) for every command shown."""
    found = []
    for page in pages():
        for line in _code_lines(page.read_text(encoding="utf-8")):
            line = re.split(r"\s#", line, maxsplit=1)[0].rstrip().rstrip("\\").rstrip()
            match = START.match(line)
            if not match:
                continue
            rest = OPERATOR.split(" " + match.group(2) + " ", maxsplit=1)[0].strip()
            if rest.startswith(("=", ".", "(", "/", ":")):
                continue  # Python or a path (`companion = Companion(...)`, `companion/loop/`)
            if not rest:
                continue  # the program named in prose (`companion`), not a command
            program = "mavsim" if match.group(1) == "mavsim" else "companion"
            found.append((str(page.relative_to(ROOT)), program, rest))
    return found


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


PARSERS = {"companion": companion_parser(), "mavsim": mavsim_parser()}


def _problems(program: str, rest: str) -> list[str]:
    parser = PARSERS[program]
    subs = _subparsers(parser)
    words = rest.split()
    # Options before the subcommand belong to the program itself (`companion -v fly`, `companion --version`).
    lead = []
    while words and words[0].startswith("-"):
        lead.append(words.pop(0))
    problems = [f"{program} does not accept {w}" for w in lead
                if w.split("=")[0] not in parser._option_string_actions]
    target = parser
    if subs:
        if not words:
            return problems if lead else [f"{program} needs a subcommand"]
        name = words[0]
        if name not in subs:
            return problems + [f"{program} has no subcommand {name!r} (has: {', '.join(sorted(subs))})"]
        target = subs[name]
        rest = " ".join(words[1:])
    else:
        rest = " ".join(words)
    for flag in FLAG.findall(rest):
        if flag.split("=")[0] not in target._option_string_actions:
            problems.append(f"{target.prog} does not accept {flag}")
    return problems


ALL = commands()


def test_the_docs_show_commands() -> None:
    """The extraction finds the README's commands (a regex that finds nothing would pass everything)."""
    shown = {(page, program, rest.split()[0] if rest else "") for page, program, rest in ALL}
    assert ("README.md", "companion", "fly") in shown
    assert ("README.md", "mavsim", "--scenario") in shown
    assert len(ALL) > 20


@pytest.mark.parametrize(("page", "program", "rest"), ALL, ids=[f"{p}:{prog} {r[:40]}" for p, prog, r in ALL])
def test_command_is_accepted_by_its_parser(page: str, program: str, rest: str) -> None:
    problems = _problems(program, rest)
    assert not problems, f"{page}: `{program} {rest}`: {'; '.join(problems)}"
