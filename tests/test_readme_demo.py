"""The README's `make demo` output is what the code prints: every line but the solve times.

The lockstep demo is deterministic for its seed; only the planner's solve times vary from
run to run. A change that moves a figure of the demo fails here until the README shows it.
"""

from __future__ import annotations

from pathlib import Path

from companion.cli import main

ROOT = Path(__file__).resolve().parents[1]
#: Lines that measure the machine, not the code.
TIMED = ("planner solve time",)


def _readme_block() -> list[str]:
    text = (ROOT / "README.md").read_text()
    start = text.index("```\n", text.index("`make demo` flies the paper's antipodal scenario")) + 4
    return text[start:text.index("```", start)].rstrip("\n").splitlines()


def test_that_the_readme_shows_what_make_demo_prints(capsys):
    assert main(["demo", "antipodal"]) == 0
    printed = capsys.readouterr().out.rstrip("\n").splitlines()
    readme = _readme_block()
    keep = lambda lines: [ln for ln in lines if not ln.startswith(TIMED)]  # noqa: E731
    assert keep(printed) == keep(readme)
    assert len(printed) == len(readme)
