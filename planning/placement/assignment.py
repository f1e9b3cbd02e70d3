"""The least-cost assignment of counter mugs to tray spots (the Hungarian method, Kuhn 1955; the
shortest-augmenting-path form with potentials, O(n² m)).

The placement's matrices are at most a few dozen rows, so plain Python is quick, and ``dishbot plan`` need
not import ``scipy.optimize`` (which brings half of SciPy along) for it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def least_cost_assignment(cost: Sequence[Sequence[float]]) -> list[tuple[int, int]]:
    """(row, column) pairs, one per row or per column whichever are fewer, with the least total cost;
    sorted by row, as ``scipy.optimize.linear_sum_assignment`` returns them."""
    if not cost or not cost[0]:
        return []
    rows, cols = len(cost), len(cost[0])
    if rows > cols:
        transposed = [[cost[r][c] for r in range(rows)] for c in range(cols)]
        return sorted((r, c) for c, r in _rows_to_columns(transposed))
    return _rows_to_columns(cost)


def _rows_to_columns(cost: Sequence[Sequence[float]]) -> list[tuple[int, int]]:
    """Every row matched to a distinct column (rows <= columns)."""
    n, m = len(cost), len(cost[0])
    u = [0.0] * (n + 1)
    v = [0.0] * (m + 1)
    match = [0] * (m + 1)  # match[j]: the row (1-based) column j holds; 0 = free
    way = [0] * (m + 1)
    for i in range(1, n + 1):
        match[0] = i
        j0 = 0
        least = [math.inf] * (m + 1)
        used = [False] * (m + 1)
        while match[j0] != 0:
            used[j0] = True
            i0, delta, j1 = match[j0], math.inf, 0
            row = cost[i0 - 1]
            for j in range(1, m + 1):
                if not used[j]:
                    reduced = row[j - 1] - u[i0] - v[j]
                    if reduced < least[j]:
                        least[j], way[j] = reduced, j0
                    if least[j] < delta:
                        delta, j1 = least[j], j
            for j in range(m + 1):
                if used[j]:
                    u[match[j]] += delta
                    v[j] -= delta
                else:
                    least[j] -= delta
            j0 = j1
        while j0:
            j1 = way[j0]
            match[j0] = match[j1]
            j0 = j1
    return sorted((match[j] - 1, j - 1) for j in range(1, m + 1) if match[j])
