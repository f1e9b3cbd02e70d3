"""PSOp, the position-based particle swarm of §4.2.5.1 (Fig 4.9-4.12), normal and improved, §5.3 parameters.

Each mug is a particle whose position is its brim centre on the tray, bounded by Eq 4.17 so the footprint
stays on the tray (handle towards +x). Mugs are taken in the sort method's order; for k = 1, 2, ... the first
k particles start from random positions and a swarm of τ_max iterations looks for an overlap-free layout of
all k (objective O, Eq 4.21-4.23: 1 only when no footprint leaves the tray or overlaps another), improving the
cost among equal O. Each iteration every particle tries a mutation (x and y swapped, Yarpiz [109]) kept if it
raises O, or keeps O and lowers the particle's cost; then personal, local and global bests are updated and
every particle moves by Eq 4.18-4.19 (improved: with probability PS by Eq 4.24, pulled also towards the
second-best particle). A coordinate leaving its bounds is clamped and its velocity mirrored. If no swarm
reaches O = 1 for k mugs, mug k and every later mug of its size are dropped and the next mug is tried; the
last overlap-free layout is the answer.

Velocities start within ±10 % of each coordinate's range (Yarpiz [109]); a new swarm (positions, velocities,
bests) starts for every k, as Fig 4.9 re-draws every position. Positions are continuous; a footprint's corner
is the centre rounded to whole millimetres, the thesis's 1 mm grid.
"""

from __future__ import annotations

from typing import NamedTuple

from description import thesis
from planning.placement.context import Candidate, Context
from planning.placement.cost import Fitness, Metrics, size_sorted

VELOCITY_FRACTION = 0.1

Point = tuple[float, float]


class _Best(NamedTuple):
    """A remembered particle: its slot, position, objective O and particle parameters then."""

    slot: int
    pos: Point
    objective: float
    metrics: Metrics


class _Swarm:
    """The k active particles' positions with their overlap counts and placement parameters, kept up to date
    one particle move at a time."""

    def __init__(self, ctx: Context, mugs: list[int]) -> None:
        p = ctx.problem
        self.ctx = ctx
        self.mugs = mugs
        self.size = [p.footprint(p.mugs[m].type) for m in mugs]
        self.radius = [fy / 2.0 for _, fy in self.size]
        tx, ty = p.tray_size_mm
        self.low = [(r, r) for r in self.radius]
        self.high = [(tx - fx + r, ty - r) for (fx, _), r in zip(self.size, self.radius, strict=True)]
        self.width = [p.mug_types[p.mugs[m].type].width_mm for m in mugs]
        self.length = [p.mug_types[p.mugs[m].type].diameter_mm for m in mugs]
        self.tray = (tx, ty)
        self.k = 0
        self.pos: list[Point] = []
        self.cx: list[int] = []
        self.cy: list[int] = []
        self.overlaps: list[int] = []
        self.outside: list[bool] = []
        self.bad = 0

    def reset(self, positions: list[Point]) -> None:
        self.k = len(positions)
        self.pos = list(positions)
        corners = [self._corner(i, q) for i, q in enumerate(positions)]
        self.cx = [c[0] for c in corners]
        self.cy = [c[1] for c in corners]
        self.overlaps = [0] * self.k
        for i in range(self.k):
            for j in range(i + 1, self.k):
                if self._overlap(i, self.cx[i], self.cy[i], j):
                    self.overlaps[i] += 1
                    self.overlaps[j] += 1
        self.outside = [self._outside(i, self.cx[i], self.cy[i]) for i in range(self.k)]
        self.bad = sum(self.overlaps) + sum(self.outside)

    def _corner(self, i: int, q: Point) -> tuple[int, int]:
        r = self.radius[i]
        return round(q[0] - r), round(q[1] - r)

    def _overlap(self, i: int, x: int, y: int, j: int) -> bool:
        (fxi, fyi), (fxj, fyj) = self.size[i], self.size[j]
        xj, yj = self.cx[j], self.cy[j]
        return x < xj + fxj and xj < x + fxi and y < yj + fyj and yj < y + fyi

    def _outside(self, i: int, x: int, y: int) -> bool:
        fx, fy = self.size[i]
        return x < 0 or y < 0 or x + fx > self.tray[0] or y + fy > self.tray[1]

    def move(self, i: int, q: Point) -> None:
        """Put particle i at q, updating every overlap count it touches (the hot loop of PSOp)."""
        self.pos[i] = q
        r = self.radius[i]
        nx, ny = round(q[0] - r), round(q[1] - r)
        ox, oy = self.cx[i], self.cy[i]
        if nx == ox and ny == oy:
            return
        fxi, fyi = self.size[i]
        cx, cy, size, overlaps = self.cx, self.cy, self.size, self.overlaps
        change = 0
        for j in range(self.k):
            if j == i:
                continue
            xj, yj = cx[j], cy[j]
            fxj, fyj = size[j]
            was = ox < xj + fxj and xj < ox + fxi and oy < yj + fyj and yj < oy + fyi
            now = nx < xj + fxj and xj < nx + fxi and ny < yj + fyj and yj < ny + fyi
            if was != now:
                delta = 1 if now else -1
                overlaps[j] += delta
                change += delta
        overlaps[i] += change
        out = self._outside(i, nx, ny)
        self.bad += 2 * change + out - self.outside[i]
        self.outside[i] = out
        self.cx[i], self.cy[i] = nx, ny

    def trial(self, i: int, q: Point) -> tuple[int, int, int, bool]:
        """What moving particle i to q would give — the bad count of Eq 4.23, i's corner and whether i would
        be placed — without moving it."""
        r = self.radius[i]
        nx, ny = round(q[0] - r), round(q[1] - r)
        ox, oy = self.cx[i], self.cy[i]
        if nx == ox and ny == oy:
            return self.bad, nx, ny, self.placed(i)
        fxi, fyi = self.size[i]
        cx, cy, size = self.cx, self.cy, self.size
        change = 0
        for j in range(self.k):
            if j == i:
                continue
            xj, yj = cx[j], cy[j]
            fxj, fyj = size[j]
            was = ox < xj + fxj and xj < ox + fxi and oy < yj + fyj and yj < oy + fyi
            now = nx < xj + fxj and xj < nx + fxi and ny < yj + fyj and yj < ny + fyi
            if was != now:
                change += 1 if now else -1
        out = self._outside(i, nx, ny)
        bad = self.bad + 2 * change + out - self.outside[i]
        return bad, nx, ny, self.overlaps[i] + change == 0 and not out

    def placed(self, i: int) -> bool:
        return self.overlaps[i] == 0 and not self.outside[i]

    def objective(self) -> float:
        """Eq 4.23."""
        return 1.0 / (1.0 + self.bad)

    def particle_metrics(self, i: int, s: int) -> Metrics:
        return self.particle_metrics_at(i, self.cx[i], self.cy[i], self.placed(i), s)

    def particle_metrics_at(self, i: int, x: int, y: int, placed: bool, s: int) -> Metrics:
        """φ_ρ of particle i with its corner at (x, y): placed or not, its area, energy and time."""
        if not placed:
            return Metrics(0, 0.0, 0.0, 0.0, s)
        dt, de = self.ctx.evaluator.move(self.mugs[i], x, y, False)
        return Metrics(1, self.ctx.evaluator.area(self.mugs[i]), de, dt, s)

    def metrics(self) -> Metrics:
        n = 0
        area = energy = seconds = 0.0
        widths, lengths = [], []
        ev = self.ctx.evaluator
        for i in range(self.k):
            if self.placed(i):
                n += 1
                dt, de = ev.move(self.mugs[i], self.cx[i], self.cy[i], False)
                area += ev.area(self.mugs[i])
                energy += de
                seconds += dt
                widths.append(self.width[i])
                lengths.append(self.length[i])
        return Metrics(n, area, energy, seconds, size_sorted(widths, lengths))

    def layout(self) -> tuple[tuple[int, int, int, bool], ...]:
        return tuple((self.mugs[i], self.cx[i], self.cy[i], False) for i in range(self.k) if self.placed(i))

    def clamp(self, i: int, q: Point) -> Point:
        (lx, ly), (hx, hy) = self.low[i], self.high[i]
        return min(max(q[0], lx), hx), min(max(q[1], ly), hy)


def run_normal(ctx: Context) -> Candidate:
    return _run(ctx, improved=False)


def run_improved(ctx: Context) -> Candidate:
    return _run(ctx, improved=True)


def _run(ctx: Context, *, improved: bool) -> Candidate:
    mugs = ctx.initial_order()
    answer: tuple[tuple[int, int, int, bool], ...] = ()
    k = 1
    while k <= len(mugs):
        swarm = _Swarm(ctx, mugs[:k])
        layout, feasible = _inner(ctx, swarm, improved=improved)
        if feasible:
            answer = layout
            k += 1
        else:
            size = ctx.problem.footprint(ctx.problem.mugs[mugs[k - 1]].type)
            mugs = mugs[: k - 1] + [
                m for m in mugs[k - 1 :] if ctx.problem.footprint(ctx.problem.mugs[m].type) != size
            ]
    return Candidate(answer)


def _inner(
    ctx: Context, swarm: _Swarm, *, improved: bool
) -> tuple[tuple[tuple[int, int, int, bool], ...], bool]:
    """One swarm of ``swarm.mugs`` (Fig 4.10-4.12); the best layout it saw and whether it is overlap-free."""
    params = thesis.PSO_PARAMS
    rng = ctx.rng
    k = len(swarm.mugs)
    swarm.reset(
        [
            (rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]))
            for lo, hi in zip(swarm.low, swarm.high, strict=True)
        ]
    )
    velocity = [
        (
            rng.uniform(-1, 1) * VELOCITY_FRACTION * (hi[0] - lo[0]),
            rng.uniform(-1, 1) * VELOCITY_FRACTION * (hi[1] - lo[1]),
        )
        for lo, hi in zip(swarm.low, swarm.high, strict=True)
    ]
    fitness = ctx.fitness
    particle_fitness = Fitness(fitness.method, fitness.cost, fitness.weights, fitness.ranking)
    personal: list[_Best | None] = [None] * k
    global_best: _Best | None = None
    previous_global: _Best | None = None
    second_best: _Best | None = None
    best_layout: tuple[tuple[tuple[int, int, int, bool], ...], float, Metrics] | None = None

    def beats(a: _Best | None, b: _Best | None) -> bool:
        """O higher, or O equal and the particle cost lower; an unset best (O = 0, cost 1) loses to any."""
        if a is None:
            return False
        if b is None or a.objective > b.objective:
            return True
        return a.objective == b.objective and particle_fitness.better(a.metrics, b.metrics)

    for tau in range(1, params.tau_max + 1):
        omega = params.w_max - (params.w_max - params.w_min) * tau / params.tau_max
        objective = swarm.objective()
        config = swarm.metrics()
        fitness.norm.observe(config)
        ctx.evaluations += 1
        particle_o = [objective] * k
        # NormalPSOp (Fig 4.11): mutate each particle, keep what helps, update the bests.
        for i in range(k):
            s = config.s
            m_i = swarm.particle_metrics(i, s)
            particle_fitness.norm.observe(m_i)
            old = swarm.pos[i]
            mutated = swarm.clamp(i, (old[1], old[0]))
            bad, corner_x, corner_y, placed = swarm.trial(i, mutated)
            o_hat = 1.0 / (1.0 + bad)
            m_hat = swarm.particle_metrics_at(i, corner_x, corner_y, placed, s)
            particle_fitness.norm.observe(m_hat)
            ctx.evaluations += 1
            if o_hat > particle_o[i] or (o_hat == particle_o[i] and particle_fitness.better(m_hat, m_i)):
                swarm.move(i, mutated)
                particle_o[i] = objective = o_hat
                m_i = m_hat
            current = _Best(i, swarm.pos[i], particle_o[i], m_i)
            if beats(current, personal[i]):
                personal[i] = current
        config = swarm.metrics()
        fitness.norm.observe(config)
        local_best: _Best | None = None
        for i in range(k):
            if beats(personal[i], local_best):
                local_best = personal[i]
        moved_global = False
        if beats(local_best, global_best):
            previous_global, global_best, moved_global = global_best, local_best, True
        if (
            best_layout is None
            or objective > best_layout[1]
            or (objective == best_layout[1] and fitness.better(config, best_layout[2]))
        ):
            best_layout = (swarm.layout(), objective, config)
        assert global_best is not None
        use_improved = False
        if improved and k >= 2:
            # ImprovedPSOp (Fig 4.12): track the second-best particle, then maybe pull towards it.
            if moved_global:
                second_best = previous_global
                for i in range(k):
                    if local_best is not None and i != local_best.slot and beats(personal[i], second_best):
                        second_best = personal[i]
            elif beats(local_best, second_best):
                second_best = local_best
            use_improved = rng.random() <= params.ps and second_best is not None
        # Eq 4.18-4.19 (improved: Eq 4.24), with velocity mirroring and position clamping.
        random, c1, c2, c3 = rng.random, params.c1, params.c2, params.c3
        pull = second_best.pos if use_improved and second_best is not None else None
        gx, gy = global_best.pos
        for i in range(k):
            own = personal[i]
            assert own is not None
            (x, y), (vx, vy), (ox, oy) = swarm.pos[i], velocity[i], own.pos
            vx = omega * vx + c1 * random() * (ox - x) + c2 * random() * (gx - x)
            if pull is not None:
                vx += c3 * random() * (pull[0] - x)
            vy = omega * vy + c1 * random() * (oy - y) + c2 * random() * (gy - y)
            if pull is not None:
                vy += c3 * random() * (pull[1] - y)
            (lx, ly), (hx, hy) = swarm.low[i], swarm.high[i]
            x, y = x + vx, y + vy
            if not lx <= x <= hx:
                vx, x = -vx, min(max(x, lx), hx)
            if not ly <= y <= hy:
                vy, y = -vy, min(max(y, ly), hy)
            velocity[i] = (vx, vy)
            swarm.move(i, (x, y))
    assert best_layout is not None
    return best_layout[0], best_layout[1] >= 1.0
