"""The README's commands table is the parser's: every subcommand has a row whose synopsis is its usage line.

A new option without its README row fails here; regenerate the synopsis cells with ``python
tests/test_readme_commands.py`` (the descriptions are kept)."""

from __future__ import annotations

import re
from pathlib import Path

from sbcal.cli.app import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"
_ROW = re.compile(r"^\| `sbcal (\w+)")


def synopses() -> dict:
    """Subcommand -> its usage line as a README cell (``-h`` left out, ``|`` escaped for the table)."""
    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    out = {}
    for name, parser in sub.choices.items():
        usage = re.sub(r"^usage:\s*", "", parser.format_usage().strip()).replace(" [-h]", "")
        out[name] = re.sub(r"\s+", " ", usage).replace("|", "\\|")
    return out


def _cells(text: str) -> dict:
    return {m.group(1): line[3:line.index("` | ")] for line in text.split("\n") if (m := _ROW.match(line))}


def test_every_subcommand_has_its_usage_in_the_readme_table():
    cells = _cells(README.read_text(encoding="utf-8"))
    want = synopses()
    assert sorted(cells) == sorted(want), "README rows and subcommands differ"
    stale = {k: (cells[k], v) for k, v in want.items() if cells[k] != v}
    assert not stale, f"README synopsis out of date (run python {Path(__file__).name}): {stale}"


if __name__ == "__main__":  # rewrite the synopsis cells from the parser
    text = README.read_text(encoding="utf-8").split("\n")
    want = synopses()
    for i, line in enumerate(text):
        m = _ROW.match(line)
        if m and m.group(1) in want:
            text[i] = "| `" + want[m.group(1)] + line[line.index("` | "):]
    README.write_text("\n".join(text), encoding="utf-8")
