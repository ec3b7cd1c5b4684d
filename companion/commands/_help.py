"""How ``--help`` prints: plain text, and a default only where there is one to show.

The descriptions are the modules' docstrings, written in reStructuredText; argparse would
print their markup (````--episodes````, ```companion identify```) as it stands.
:class:`PlainHelpFormatter` (every ``companion`` parser's, :class:`companion.cli.OneLineErrorParser`)
strips the backticks from descriptions and argument help; :class:`DefaultsHelpFormatter`
also appends ``(default: X)`` to an option's help unless the help already says its default
or the option has none (``None``, ``False``).
"""

from __future__ import annotations

import argparse
import re

_LITERAL = re.compile(r"``([^`]*)``|`([^`]*)`")


def plain(text: str) -> str:
    """``text`` without reStructuredText's backticks: ````x```` and ```x``` become ``x``."""
    return _LITERAL.sub(lambda m: m.group(1) if m.group(1) is not None else m.group(2), text)


class PlainHelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, with the reStructuredText backticks stripped (:func:`plain`)."""

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain(text))

    def _expand_help(self, action: argparse.Action) -> str:
        return plain(super()._expand_help(action))


class PlainRawDescriptionHelpFormatter(PlainHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """The description's own line breaks kept (a docstring laid out as paragraphs), backticks stripped."""


class DefaultsHelpFormatter(PlainHelpFormatter):
    """Every option's default appended to its help, where it has one and the help does not give it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (not action.option_strings or default is None or default is False or default is argparse.SUPPRESS
                or "default:" in text or "(default" in text or "%(default)" in text):
            return text
        if isinstance(default, (list, tuple)):
            shown = ",".join(str(x) for x in default).replace("%", "%%")
            return f"{text} (default: {shown})"
        return f"{text} (default: %(default)s)"
