"""A small binary-coded genetic algorithm (minimises a cost), seeded and reproducible.

Classic SGA operators: binary tournament selection, single-point crossover with
probability ``crossover`` per pair, independent bit-flip mutation with
probability ``mutation`` per bit, and elitism of one (the best genome so far is
carried into the next generation, so the best cost never gets worse). Costs are
cached per genome: with 20 x 20 evaluations and short genomes many children
repeat their parents.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from dataclasses import dataclass, field

import numpy as np


@dataclass
class GAResult:
    best_genome: tuple
    best_cost: float
    history: list  # per generation: {"generation", "best", "mean"}
    evaluations: int  # distinct genomes evaluated (cache misses)
    calls: int  # cost requests including cache hits
    cache: dict = field(repr=False, default_factory=dict)


def binary_ga(cost: Callable[[tuple[int, ...]], float], n_bits: int, population: int = 20, crossover: float = 0.8, mutation: float = 0.005, generations: int = 20, seed: int = 0) -> GAResult:
    """Minimise ``cost(genome_tuple_of_0_1) -> float`` over ``n_bits``-bit strings."""
    if population < 2 or population % 2:
        raise ValueError("population must be an even number >= 2, got %r" % population)
    if not 0.0 <= crossover <= 1.0 or not 0.0 <= mutation <= 1.0:
        raise ValueError("crossover and mutation are probabilities in [0, 1]")
    if generations < 1 or n_bits < 1:
        raise ValueError("generations and n_bits must be >= 1")
    rng = np.random.default_rng(seed)
    cache = {}
    calls = 0

    def cost_of(pop):
        nonlocal calls
        out = np.empty(len(pop))
        for i, g in enumerate(pop):
            key = tuple(int(b) for b in g)
            calls += 1
            if key not in cache:
                cache[key] = float(cost(key))
            out[i] = cache[key]
        return out

    pop = rng.integers(0, 2, size=(population, n_bits), dtype=np.int8)
    costs = cost_of(pop)
    history = []
    best_i = int(np.argmin(costs))
    best, best_cost = pop[best_i].copy(), float(costs[best_i])
    history.append({"generation": 0, "best": best_cost, "mean": float(np.mean(costs))})
    for gen in range(1, generations + 1):
        a = rng.integers(0, population, size=population)
        b = rng.integers(0, population, size=population)
        parents = pop[np.where(costs[a] <= costs[b], a, b)]
        children = parents.copy()
        do_x = rng.random(population // 2) < crossover
        cut = rng.integers(1, n_bits, size=population // 2) if n_bits > 1 else np.zeros(population // 2, int)
        for i in np.flatnonzero(do_x):
            c = cut[i]
            children[2 * i, c:], children[2 * i + 1, c:] = parents[2 * i + 1, c:], parents[2 * i, c:]
        flips = rng.random(children.shape) < mutation
        children ^= flips.astype(np.int8)
        children[0] = best  # elitism
        pop = children
        costs = cost_of(pop)
        i = int(np.argmin(costs))
        if costs[i] < best_cost:
            best, best_cost = pop[i].copy(), float(costs[i])
        history.append({"generation": gen, "best": best_cost, "mean": float(np.mean(costs))})
    return GAResult(tuple(int(v) for v in best), best_cost, history, len(cache), calls, cache)


def decode_uint(bits: Sequence[int]) -> int:
    v = 0
    for b in bits:
        v = (v << 1) | int(b)
    return v
