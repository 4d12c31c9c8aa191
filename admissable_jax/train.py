"""``python -m admissable_jax.train key=value ...``: train one agent from the command line.

``--help`` lists every key with its default. Bad settings exit with status 2 and a one-line
message; a corrupt checkpoint, a diverged run (NaN) or a run too large for the device's
memory exits with status 1, and the run directory keeps everything finished before.
"""

from __future__ import annotations

import sys

from admissable_jax.cli import enable_compilation_cache, parse_args
from admissable_jax.config import TrainConfig
from admissable_jax.runs import run_from_cli, train_fn


def main(argv: list[str]) -> int:
    config = parse_args(
        TrainConfig, argv, "admissable_jax.train",
        "Train SAC against adversarial (or uniform) missingness on an MJX Gymnasium v5 env.",
        validate=lambda c: c.resolved(),
    )
    enable_compilation_cache()
    result, status = run_from_cli(train_fn, config)
    if status:
        return status
    last = result.scores[-1]
    print(
        f"done: {result.config.env} {result.config.missingness}, {last['env_steps']} env steps, "
        f"min_u a_u {last['min_score']:.1f} (u = {last['argmin_set']}), clean {last['clean_score']:.1f}; "
        f"run in {result.run_dir}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
