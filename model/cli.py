"""The command lines' common form: ``usage: python -m <module>``, the module docstring's whole
first paragraph as the description, the options, and examples to copy."""

from __future__ import annotations

import argparse
import textwrap

WIDTH = 79


def description(doc: str | None) -> str:
    """The first paragraph of a module docstring, re-wrapped (never cut mid-sentence)."""
    first = (doc or "").strip().split("\n\n")[0].replace("``", "")
    return textwrap.fill(" ".join(first.split()), WIDTH)


def command_parser(prog: str, doc: str | None, examples: list[str], **kwargs) -> argparse.ArgumentParser:
    """An ArgumentParser for ``python -m ...`` whose help reads in full: its name, what it does
    (``doc``'s first paragraph) and ``examples`` (command lines, shown as they are)."""
    epilog = "examples:\n" + "\n".join(f"  {e}" for e in examples)
    return argparse.ArgumentParser(prog=prog, description=description(doc), epilog=epilog,
                                   formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)
