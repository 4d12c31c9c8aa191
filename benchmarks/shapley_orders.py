"""How many feature orders the Shapley estimate needs: the permutation estimate against the exact values.

    python benchmarks/shapley_orders.py audit=DIR/audit.json orders=4,8,16,32,64,128 repeats=200

``audit`` is an audit written with ``shapley=exact`` (``audit.json`` keeps every coalition's
value, the mean over its N episodes). For each M in ``orders`` and ``repeats`` seeds, the
permutation estimate (``plan_shapley(d, M, seed)``, antithetic pairs) is computed from those
same values, so only the choice of orders differs from the exact attribution, and compared
with it:

- ``rmse`` and ``max_error``: over the features and seeds, |φ̂_i − φ_i| (return units), also
  relative to v(all) − v(none);
- ``coverage``: how often φ_i lies inside the estimate's 95% interval over its orders' pairs
  (the interval the report adds for an estimate), per feature and seed;
- ``top_agrees``: how often the estimate names the exact attribution's most valuable feature;
- ``coalitions``: distinct coalitions the M orders value (what a rollout would pay for),
  against 2^d.

No rollouts: NumPy on the stored values, seconds. It appends one record per M to
``results/shapley_orders.jsonl`` and prints the table.
"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np

from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.scoring.attribution import plan_shapley, shapley_attribution
from common import append_record, run_benchmark


@dataclasses.dataclass
class ShapleyOrdersConfig:
    audit: str = dataclasses.field(default="", metadata={"help": "an audit.json written with shapley=exact"})
    orders: str = dataclasses.field(default="4,8,16,32,64,128", metadata={"help": "comma list of M"})
    repeats: int = dataclasses.field(default=200, metadata={"help": "seeds of the orders per M"})


def exact_values(path: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """(hidden rows (2^d, d), their values (2^d, 1), the exact attribution) of an exact audit."""
    with open(path) as file:
        record = json.load(file)
    attribution = record.get("shapley") or {}
    if attribution.get("method") != "exact" or "coalition_values" not in attribution:
        raise ValueError(f"{path} holds no exact Shapley attribution with its coalition values (audit shapley=exact)")
    d = len(record["feature_names"])
    rows = np.zeros((len(attribution["coalition_values"]), d), np.float32)
    for row, (hidden, _) in zip(rows, attribution["coalition_values"]):
        row[hidden] = 1.0
    values = np.array([[value] for _, value in attribution["coalition_values"]])
    return rows, values, {**attribution, "env": record["env"], "names": record["feature_names"]}


def _validate(config: ShapleyOrdersConfig) -> None:
    check_at_least_one(config, ("repeats",))


def main(argv: list[str]) -> int:
    config = parse_args(ShapleyOrdersConfig, argv, "benchmarks/shapley_orders.py", __doc__.splitlines()[0], _validate)
    try:
        rows, values, exact = exact_values(config.audit)
    except (OSError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    d, truth = rows.shape[1], np.array(exact["values"])
    worth = exact["full"] - exact["blind"]
    print(f"{exact['env']}: d = {d}, v(all) − v(none) = {worth:.1f}, most valuable: {exact['names'][truth.argmax()]}")
    print("| M | coalitions | RMSE | max error | coverage of the 95% interval | top feature agrees |")
    print("|---|---|---|---|---|---|")
    for orders in [int(part) for part in config.orders.split(",")]:
        if plan_shapley(d, orders).method == "exact":
            print(f"| {orders} | (M orders would value all {2**d}: the exact attribution itself) | | | | |")
            continue
        errors, covered, top, coalitions = [], [], [], []
        for seed in range(config.repeats):
            plan = plan_shapley(d, orders, seed)
            estimate = shapley_attribution(plan, rows, values)
            error = np.asarray(estimate.values) - truth
            errors.append(error)
            covered.append(np.abs(error) <= np.asarray(estimate.ci95_orders))
            top.append(int(np.argmax(estimate.values)) == int(truth.argmax()))
            coalitions.append(estimate.coalitions)
        errors = np.array(errors)
        record = {"env": exact["env"], "audit": config.audit, "d": d, "orders": orders, "repeats": config.repeats,
                  "coalitions": float(np.mean(coalitions)), "coalitions_exact": 2**d,
                  "rmse": float(np.sqrt((errors**2).mean())), "max_error": float(np.abs(errors).max()),
                  "rmse_relative": float(np.sqrt((errors**2).mean()) / abs(worth)),
                  "coverage": float(np.mean(covered)), "top_agrees": float(np.mean(top))}
        append_record("shapley_orders", record)
        print(f"| {orders} | {record['coalitions']:.0f} of {2**d} | {record['rmse']:.2f} "
              f"({100 * record['rmse_relative']:.1f}%) | {record['max_error']:.2f} | {record['coverage']:.3f} | "
              f"{record['top_agrees']:.3f} |")
    return 0


if __name__ == "__main__":
    run_benchmark(main)
