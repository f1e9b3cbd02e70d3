"""The least-cost assignment of a cost matrix's rows to its columns: scipy's ``linear_sum_assignment``
(Crouse's shortest augmenting paths, in scipy's order, so ties go the same way), written out.

Two callers: the lost-mug association (which seen mug is which known one, by distance) and the placement
(which counter mug goes to which tray spot, by move energy). Their matrices are a few dozen rows at most, so
plain Python is quick, and neither a daemon looking again at the counter (0.9 s of CPU on its event loop)
nor ``dishbot plan`` pays to import ``scipy.optimize``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def least_cost_assignment(cost: Sequence[Sequence[float]]) -> list[tuple[int, int]]:
    """The (row, column) pairs of a minimum-cost assignment of a finite cost matrix (as many pairs as
    its shorter side), by row: scipy's ``linear_sum_assignment``, the same shortest augmenting paths in
    the same order, so ties go the same way."""
    if not cost or not cost[0]:
        return []
    transposed = len(cost[0]) < len(cost)
    rows = [list(column) for column in zip(*cost, strict=True)] if transposed else [list(r) for r in cost]
    col4row = _augmented(rows)
    if transposed:  # rows of the transposed matrix are the columns: give them back by original row
        return sorted((c, r) for r, c in enumerate(col4row))
    return list(enumerate(col4row))


def _augmented(cost: list[list[float]]) -> list[int]:
    """The column each row gets (rows no more than columns): Crouse's shortest augmenting path method,
    one row at a time, keeping the dual variables ``u`` and ``v``."""
    n_rows, n_cols = len(cost), len(cost[0])
    u, v = [0.0] * n_rows, [0.0] * n_cols
    col4row, row4col = [-1] * n_rows, [-1] * n_cols
    for row in range(n_rows):
        sink, low, path, costs, rows_seen, cols_seen = _shortest_path(cost, u, v, row4col, row)
        u[row] += low
        for i in range(n_rows):
            if rows_seen[i] and i != row:
                u[i] += low - costs[col4row[i]]
        for j in range(n_cols):
            if cols_seen[j]:
                v[j] -= low - costs[j]
        j = sink
        while True:  # augment along the path back to this row
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == row:
                break
    return col4row


def _shortest_path(
    cost: list[list[float]], u: list[float], v: list[float], row4col: list[int], row: int
) -> tuple[int, float, list[int], list[float], list[bool], list[bool]]:
    """The free column that ``row`` reaches at the least reduced cost, that cost, the path's predecessor
    row of every column, the shortest costs and the rows and columns scanned."""
    n_rows, n_cols = len(cost), len(cost[0])
    remaining = list(range(n_cols - 1, -1, -1))  # scipy's order: a constant matrix gives the identity
    rows_seen, cols_seen = [False] * n_rows, [False] * n_cols
    costs = [math.inf] * n_cols
    path = [-1] * n_cols
    low = 0.0
    i = row
    while True:
        index, lowest = -1, math.inf
        rows_seen[i] = True
        for it, j in enumerate(remaining):
            r = low + cost[i][j] - u[i] - v[j]
            if r < costs[j]:
                path[j] = i
                costs[j] = r
            # Of equal costs, one that ends the path (a free column) wins.
            if costs[j] < lowest or (costs[j] == lowest and row4col[j] == -1):
                lowest, index = costs[j], it
        low = lowest
        j = remaining[index]
        cols_seen[j] = True
        remaining[index] = remaining[-1]
        remaining.pop()
        if row4col[j] == -1:
            return j, low, path, costs, rows_seen, cols_seen
        i = row4col[j]
