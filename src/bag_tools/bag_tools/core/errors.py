"""The single exception type of bag_tools."""

from __future__ import annotations


class BagError(Exception):
    """Any failure on bad input: one readable line, quoting the offending value."""

    def __init__(self, message: str) -> None:
        super().__init__(one_line(message))


def one_line(text: object) -> str:
    """Collapse a message to a single line (wrapped library errors may span lines)."""
    return ' '.join(str(text).split())
