"""The command line's argument types: values refused before any work when they mean nothing.

Each is an argparse ``type=`` (:func:`number` and the constants made with it, :func:`local_workers`,
:func:`image_size`); argparse puts the option's name before the message, and :mod:`hbeo.cli` turns it into one
line, ``error: OPTION: problem``, exit status 2. :func:`join_list_values` lets a list option's value start with
``-``. Imports argparse and the foundation only.
"""
from __future__ import annotations

import argparse
import math


def number(kind, lo=None, hi=None, lo_open=False, hi_open=False):
    """An argparse ``type=``: ``kind`` (int or float) finite and in [lo, hi] (open ends where asked); the
    error (argparse puts the option's name before it) says what it takes and what it got."""
    name = "a whole number" if kind is int else "a number"
    rng = " and ".join(x for x in (lo is not None and f"{'>' if lo_open else '>='} {lo}",
                                   hi is not None and f"{'<' if hi_open else '<='} {hi}") if x)

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            v = None
        ok = v is not None and math.isfinite(v) and (lo is None or (v > lo if lo_open else v >= lo)) \
            and (hi is None or (v < hi if hi_open else v <= hi))
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {name}{' ' + rng if rng else ''}, got {text!r}")
        return v
    parse.__name__ = name
    return parse


COUNT = number(int, 1)                             #: epochs, views, rolls, steps, objects: at least one
NONNEG = number(int, 0)                            #: workers, seeds
POSITIVE = number(float, 0, lo_open=True)          #: distances, scales
FRACTION = number(float, 0, 1, lo_open=True)       #: (0, 1]
OPEN_FRACTION = number(float, 0, 1, True, True)    #: (0, 1)
#: options whose value may start with "-" (a list of numbers): joined to it before parsing, so a
#: negative first number reaches the option's own check instead of argparse's usage text
LIST_OPTIONS = ("--intrinsics", "--loss-weights", "--fc", "--verify-set")


def local_workers(text: str) -> int:
    """An argparse ``type=`` for ``--workers``: a whole number >= 0, 0 meaning one process per core this
    process may run on (:func:`hbeo.limits.usable_cores`). Not given: None, the profile's count."""
    n = NONNEG(text)
    if n == 0:
        from hbeo.limits import usable_cores
        return usable_cores()
    return n


def image_size(text: str) -> tuple[int, int]:
    """An argparse ``type=`` for ``--image-size W,H``: two whole numbers, 8 to 4096 pixels each."""
    parts = text.replace("x", ",").split(",")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected W,H (two whole numbers of pixels), got {text!r}") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"expected 8 to 4096 pixels each, got {text!r}")
    return (w, h)


def join_list_values(argv: list[str]) -> list[str]:
    out, i = [], 0
    while i < len(argv):
        if argv[i] in LIST_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out
