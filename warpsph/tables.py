"""Cells and tables of the studies, shared by sweeps, the Pareto study and the plots: a cell's text and the Pareto
front of a table's rows."""

from __future__ import annotations

import math


def value_text(v):
    """A table cell's text: 4 significant digits, a models list as rankine(beta=0.5), None as —."""
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        if v and all(isinstance(m, dict) and "type" in m for m in v):
            return " + ".join(f"{m['type']}(" + ", ".join(f"{k}={value_text(x)}" for k, x in m.items() if k != "type") + ")"
                              for m in v)
        return "[" + ", ".join(value_text(x) for x in v) + "]"
    return str(v)


def pareto_flags(points, x, y):
    """Per point: True when no other point has both a lower ``x`` and a lower ``y`` (strictly), False
    when one has, None when the point has no finite ``x`` and ``y`` (unstable, or not measured).
    Sort and sweep: a point is dominated iff the least ``y`` among the points of strictly smaller ``x``
    is below its own."""
    def value(p, key):
        v = p.get(key)
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None

    flags = [None] * len(points)
    valid = sorted((value(p, x), value(p, y), n) for n, p in enumerate(points)
                   if value(p, x) is not None and value(p, y) is not None)
    best = math.inf  # least y among the points of strictly smaller x
    k = 0
    while k < len(valid):
        group = [v for v in valid[k:] if v[0] == valid[k][0]]  # equal x: they do not dominate each other
        for _, yv, n in group:
            flags[n] = not best < yv
        best = min(best, min(v[1] for v in group))
        k += len(group)
    return flags
