"""What each observation feature is worth to a policy: Shapley values of the missingness game.

The paper closes by naming connections to explainable AI as future work; missingness is one
already. Its features are the players of a cooperative game in which a coalition S of
*visible* features is worth v(S), the policy's mean return with every feature outside S
hidden (the agent's own masking: zeros and the 0/1 indicator). v(F) is the clean return,
v(∅) the return with nothing seen. Feature i's Shapley value

    φ_i = Σ_{S ⊆ F∖{i}} |S|! (d − |S| − 1)! / d! · (v(S ∪ {i}) − v(S))

is its share of what seeing is worth: Σ_i φ_i = v(F) − v(∅) (efficiency). A game and its dual
share their Shapley values, so φ_i is as well feature i's share of the loss from hiding
everything. Beside it stands the leave-one-out loss v(F) − v(F∖{i}) = clean − a_{i}, which is
all the paper's k = 1 adversary sees: a feature with a large φ_i and a small leave-one-out loss
carries information that other features carry too. Hidden alone it costs little; hidden with
those others it costs much, which an adversary of larger k finds.

Exact where the 2^d coalitions are no more than the Monte Carlo estimate would value (Hopper,
d = 11: 2,048); else the permutation estimate (Castro, Gómez & Tejada 2009) over M random
orders of the features in antithetic pairs (an order and its reverse): each order gives
every feature one marginal contribution, and an order's contributions sum to v(F) − v(∅)
exactly, so the estimate is efficient too.

Every number here is NumPy: the values come from any scorer (the audit's batched rollout,
a Gymnasium policy's), one row per hidden set.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from admissable_jax.scoring.worst_set import t_half_width


MIN_ORDERS = 4  # two antithetic pairs: the fewest that give the permutation estimate an interval
MAX_EXACT_FEATURES = 20  # 2^20 coalitions; beyond, only the permutation estimate


@dataclasses.dataclass(frozen=True)
class ShapleyPlan:
    """Which hidden sets the attribution needs valued, and how it combines them."""

    num_features: int
    hidden_rows: np.ndarray  # (m, d) float32 0/1: distinct hidden sets (the empty one, the clean case, included)
    orders: np.ndarray | None  # (M, d) the feature orders of the permutation estimate; None: exact

    @property
    def method(self) -> str:
        return "exact" if self.orders is None else "permutation"


@dataclasses.dataclass
class ShapleyAttribution:
    """φ_i per feature (module docstring), with what they are estimated from."""

    method: str  # exact (every coalition) | permutation (M random orders, antithetic pairs)
    orders: int  # M; 0 where exact
    coalitions: int  # distinct coalitions valued
    values: list[float]  # φ_i, feature order
    ci95_starts: list[float]  # 95% half-width over the N episodes (start states): Student's t of each episode's φ_i
    ci95_orders: list[float]  # 95% half-width over the M/2 antithetic pairs of orders; 0 where exact
    leave_one_out: list[float]  # v(F) − v(F∖{i}): the loss of hiding feature i alone
    full: float  # v(F): the clean return
    blind: float  # v(∅): every feature hidden
    coalition_values: list  # [[hidden features], v] of every coalition valued (mean over the N episodes)

    @property
    def ci95(self) -> np.ndarray:
        """Both intervals' half-widths combined, as independent errors add."""
        return np.hypot(self.ci95_starts, self.ci95_orders)


def plan_shapley(num_features: int, orders: int | str, seed: int = 0) -> ShapleyPlan:
    """The plan for ``orders`` (M ≥ 4; rounded up to even, for antithetic pairs) random
    feature orders, or the exact one where 2^d coalitions are no more than the M·(d − 1) + 2
    the orders visit, or where ``orders`` is ``"exact"``. Raises ValueError for M < 4, for
    d < 1, and for "exact" beyond d = 20."""
    d = num_features
    if orders == "exact" and not 1 <= d <= MAX_EXACT_FEATURES:
        raise ValueError(f"exact Shapley values of d = {d} features value 2^{d} coalitions; "
                         f"give a number of feature orders instead")
    if orders != "exact" and (not isinstance(orders, (int, np.integer)) or orders < MIN_ORDERS or d < 1):
        raise ValueError(f"a Shapley attribution needs exact or at least {MIN_ORDERS} feature orders, and a feature; "
                         f"got {orders!r} and d = {d}")
    if orders == "exact" or 2**d <= (orders + orders % 2) * (d - 1) + 2:
        return ShapleyPlan(d, _bits(np.arange(2**d), d), None)
    orders = int(orders) + int(orders) % 2
    rng = np.random.default_rng(seed)
    first = np.stack([rng.permutation(d) for _ in range(orders // 2)])
    order_table = np.stack([first, first[:, ::-1]], axis=1).reshape(orders, d)  # each order, then its reverse
    visited = np.concatenate([_order_coalitions(order, d) for order in order_table] + [np.eye(d, dtype=np.float32)])
    return ShapleyPlan(d, np.unique(visited, axis=0), order_table)


def _bits(indices: np.ndarray, d: int) -> np.ndarray:
    """Row j has feature i hidden where bit i of ``indices[j]`` is set."""
    return ((indices[:, None] >> np.arange(d)) & 1).astype(np.float32)


def _order_coalitions(order: np.ndarray, d: int) -> np.ndarray:
    """(d + 1, d) hidden rows along ``order``: row t hides every feature but the first t."""
    hidden = np.ones((d + 1, d), np.float32)
    for t, feature in enumerate(order):
        hidden[t + 1:, feature] = 0.0
    return hidden


def shapley_attribution(plan: ShapleyPlan, hidden_rows: np.ndarray, returns: np.ndarray) -> ShapleyAttribution:
    """φ by ``plan`` from the valued sets: ``hidden_rows`` ((r, d) 0/1, each of the plan's
    rows among them) and their per-episode values ``returns`` ((r, N), episode n of every row
    from one start state where the scorer shares them). Raises ValueError for a plan row
    without a value."""
    d = plan.num_features
    hidden_rows, returns = np.asarray(hidden_rows), np.asarray(returns, np.float64)
    if hidden_rows.ndim != 2 or hidden_rows.shape[1] != d or returns.shape[:1] != hidden_rows.shape[:1]:
        raise ValueError(f"need (r, {d}) hidden rows and (r, N) returns, got {hidden_rows.shape} and {returns.shape}")
    row_of = {_key(row): index for index, row in enumerate(hidden_rows)}
    missing = [np.flatnonzero(row).tolist() for row in plan.hidden_rows if _key(row) not in row_of]
    if missing:
        raise ValueError(f"no value for {len(missing)} of the plan's hidden sets, e.g. {missing[0]}")

    def value(rows: np.ndarray) -> np.ndarray:  # (..., d) hidden rows -> (..., N) returns
        indices = np.array([row_of[_key(row)] for row in rows.reshape(-1, d)])
        return returns[indices].reshape(*rows.shape[:-1], returns.shape[1])

    if plan.orders is None:
        per_episode = _exact_shapley(value(plan.hidden_rows), d)  # (d, N)
        per_order = None
    else:
        along = value(np.stack([_order_coalitions(order, d) for order in plan.orders]))  # (M, d + 1, N)
        gains = along[:, 1:] - along[:, :-1]  # (M, d, N): the t-th feature's marginal contribution
        contributions = np.zeros_like(gains)
        contributions[np.arange(len(plan.orders))[:, None], plan.orders] = gains  # by feature, not by position
        per_episode = contributions.mean(axis=0)
        per_order = contributions.mean(axis=2).reshape(-1, 2, d).mean(axis=1)  # (M/2, d): antithetic pairs
    full, blind = value(np.zeros((1, d), np.float32))[0], value(np.ones((1, d), np.float32))[0]
    alone = value(np.eye(d, dtype=np.float32))  # (d, N)
    return ShapleyAttribution(
        method=plan.method, orders=0 if plan.orders is None else len(plan.orders), coalitions=len(plan.hidden_rows),
        values=per_episode.mean(axis=1).tolist(), ci95_starts=t_half_width(per_episode, axis=1).tolist(),
        ci95_orders=(np.zeros(d) if per_order is None else t_half_width(per_order, axis=0)).tolist(),
        leave_one_out=(full.mean() - alone.mean(axis=1)).tolist(), full=float(full.mean()), blind=float(blind.mean()),
        coalition_values=[[np.flatnonzero(row).tolist(), float(value(row[None])[0].mean())] for row in plan.hidden_rows])


def _exact_shapley(values: np.ndarray, d: int) -> np.ndarray:
    """φ (d, N) from ``values`` (2^d, N), row h the coalition hiding the features of h's bits."""
    hidden_count = _bits(np.arange(2**d), d).sum(axis=1).astype(int)
    weight = np.array([math.factorial(s) * math.factorial(d - s - 1) / math.factorial(d) for s in range(d)])
    phi = np.zeros((d, values.shape[1]))
    for feature in range(d):
        hidden = np.flatnonzero((np.arange(2**d) >> feature) & 1)  # coalitions S without the feature
        seen = hidden ^ (1 << feature)  # S ∪ {feature}
        phi[feature] = (weight[d - hidden_count[hidden]][:, None] * (values[seen] - values[hidden])).sum(axis=0)
    return phi


def _key(row: np.ndarray) -> bytes:
    return np.asarray(row).astype(bool).tobytes()
