"""Text made to fit a width: a path shortened in its middle (its start and its file name stay
readable) rather than wrapped mid-word. Pure: the width of a text is measured by the caller's
``measure`` (imgui.calc_text_size in the panel)."""

from __future__ import annotations

ELLIPSIS = "..."  # imgui's default font has no single-character ellipsis glyph


def middle_ellipsis(text: str, max_width: float, measure) -> str:
    """``text`` if measure(text) <= max_width, else its first and last characters around
    ELLIPSIS, as many as fit (the end gets the extra one: a path's file name matters most).
    measure: str -> width; at least the ellipsis is returned however narrow max_width is."""
    if measure(text) <= max_width:
        return text
    low, high = 0, len(text)  # characters kept: the largest count that fits
    while low < high:
        keep = (low + high + 1) // 2
        if measure(_shortened(text, keep)) <= max_width:
            low = keep
        else:
            high = keep - 1
    return _shortened(text, low)


def _shortened(text: str, keep: int) -> str:
    """``keep`` characters of ``text``: keep // 2 from its start, the rest from its end."""
    head = keep // 2
    tail = keep - head
    return text[:head] + ELLIPSIS + (text[len(text) - tail:] if tail else "")
