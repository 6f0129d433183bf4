"""Small helpers shared by the report's and the studies' figures.

``plain_log_axis`` labels a log axis with plain numbers (20, 0.05, 1000) instead of matplotlib's
scientific labels ("2x10^1"), which read badly on axes of errors in mm and rates in fps.
"""

from __future__ import annotations

import numpy as np
from matplotlib.ticker import LogFormatter


class PlainLogFormatter(LogFormatter):
    """matplotlib's choice of which log ticks to label, written as plain numbers."""

    def __call__(self, x, pos=None) -> str:
        if not super().__call__(x, pos):  # a tick matplotlib leaves unlabelled (too crowded)
            return ""
        return plain_number(x)


def plain_number(x: float) -> str:
    """20.0 -> "20", 0.05 -> "0.05", 1e6 -> "1000000" (no exponent)."""
    return np.format_float_positional(float(x), precision=6, trim="-")


def plain_log_axis(ax, which: str = "y") -> None:
    """Put ``ax`` on a log scale along ``which`` ("x" or "y") with plain-number tick labels."""
    axis = ax.yaxis if which == "y" else ax.xaxis
    (ax.set_yscale if which == "y" else ax.set_xscale)("log")
    axis.set_major_formatter(PlainLogFormatter(labelOnlyBase=False))
    axis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.4)))
