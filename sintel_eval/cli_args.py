"""argparse value types shared by the ``python -m sintel_eval`` sub-commands."""
from __future__ import annotations

import argparse


def size_arg(text: str) -> tuple[int, int]:
    """``WxH`` -> (w, h) in px, at least 16x9."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a size: write WxH, e.g. 320x180") from None
    if w < 16 or h < 9:
        raise argparse.ArgumentTypeError(f"size {w}x{h} is too small: use at least 16x9")
    return w, h


def _int_at_least(text: str, minimum: int, rule: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"{value} {rule}")
    return value


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    return _int_at_least(text, 1, "must be at least 1")


def non_negative_int(text: str) -> int:
    """A whole number >= 0 (0 = none)."""
    return _int_at_least(text, 0, "must be 0 (none) or more")


def float_range(text: str) -> tuple[float, float]:
    """``MIN,MAX`` -> (min, max) floats with min <= max."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a range: write MIN,MAX, e.g. -12,0") from None
    if lo > hi:
        raise argparse.ArgumentTypeError(f"range {text}: MIN must not exceed MAX")
    return lo, hi
