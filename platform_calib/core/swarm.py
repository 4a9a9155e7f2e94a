"""The particle swarm behind the source's compensation: pymoo's PSO with fixed
coefficients over box-bounded feed corrections (a module of its own because pymoo loads
scipy's optimisers, which only this method needs)."""
from __future__ import annotations

import numpy as np
from pymoo.algorithms.soo.nonconvex.pso import PSO
from pymoo.core.callback import Callback
from pymoo.core.problem import Problem
from pymoo.optimize import minimize


def minimise_swarm(cost, lower, upper, settings) -> tuple:
    """Minimise ``cost`` (vectorised over the swarm's (n, 3) corrections, m) within
    [``lower``, ``upper``] with the swarm ``settings`` (a PSOSettings).

    Returns
    -------
    best : float
        The best cost found (m).
    correction : ndarray, shape (3,)
        The corrections that reach it (m).
    history : list of float
        The swarm's best cost after each iteration, the initial swarm first (m).
    """
    problem = _CostProblem(cost, lower, upper)
    swarm = PSO(pop_size=settings.particles, w=settings.inertia, c1=settings.c1,
                c2=settings.c2, adaptive=False, pertube_best=False,
                # The source's update with no velocity clamp inside the bounds.
                max_velocity_rate=1.0)
    best_costs = _BestCost()
    # An iteration evaluates the swarm and records its best (the initial swarm is the
    # first), as the source counts them.
    result = minimize(problem, swarm, ('n_gen', settings.iterations), seed=settings.seed,
                      callback=best_costs, verbose=False)
    return float(result.F[0]), np.asarray(result.X, dtype=float), best_costs.history


class _CostProblem(Problem):
    """A cost over the swarm's (n, 3) corrections, vectorised, within box bounds (m)."""

    def __init__(self, cost, lower, upper):
        super().__init__(n_var=len(lower), n_obj=1, xl=lower, xu=upper)
        self.cost = cost

    def _evaluate(self, x, out, *args, **kwargs):
        out['F'] = self.cost(x)


class _BestCost(Callback):
    """The swarm's best cost after each generation (m)."""

    def __init__(self):
        super().__init__()
        self.history = []

    def notify(self, algorithm):
        self.history.append(float(algorithm.opt[0].F[0]))
