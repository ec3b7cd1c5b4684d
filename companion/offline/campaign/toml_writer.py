"""A TOML writer for the subset of TOML scenario files use (``tomllib`` only reads).

The campaign flies generated episodes from their parsed tables (no files); this writer
saves one as a file (``companion campaign --episode I --save-scenario FILE``) so that
``companion demo`` and ``mavsim`` can fly the same encounter.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from companion.errors import InputError

def _toml_value(v: Any, where: str) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            raise InputError(f"TOML writer: {where} is not finite ({v!r})")
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x, where) for x in v) + "]"
    raise InputError(f"TOML writer: {where} has unsupported type {type(v).__name__}")


def to_toml(data: dict) -> str:
    """Serialise the subset of TOML scenarios use: tables, arrays of tables, scalars, nested lists.

    A list of dicts becomes an array of tables (``[[a.b]]``); a dict becomes a table.
    Plain keys in a table come before its sub-tables, as TOML requires.
    """
    lines: list[str] = []

    def emit(table: dict, prefix: str, header: str | None) -> None:
        plain = {k: v for k, v in table.items() if not _is_table(v) and not _is_table_array(v)}
        if header is not None and (plain or not any(_is_table(v) or _is_table_array(v) for v in table.values())):
            lines.append(header)
            for k, v in plain.items():
                lines.append(f"{k} = {_toml_value(v, prefix + k)}")
            lines.append("")
        elif plain:  # top-level keys (no header)
            lines.extend(f"{k} = {_toml_value(v, prefix + k)}" for k, v in plain.items())
            lines.append("")
        for k, v in table.items():
            name = prefix + k
            if _is_table(v):
                emit(v, name + ".", f"[{name}]")
            elif _is_table_array(v):
                for item in v:
                    emit(item, name + ".", f"[[{name}]]")

    emit(data, "", None)
    return "\n".join(lines).rstrip() + "\n"


def _is_table(v: Any) -> bool:
    return isinstance(v, dict)


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)



def write_scenario(data: dict, path: str | Path) -> Path:
    """Write a scenario dict as TOML; returns the path."""
    path = Path(path)
    path.write_text(to_toml(data))
    return path
