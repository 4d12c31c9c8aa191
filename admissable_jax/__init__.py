"""admissable_jax: training RL agents against adversarial missingness, in JAX on MJX."""

import contextlib
import io

# MJX prints an import failure when warp-lang is absent; physics=jax needs no Warp (and
# physics=warp says clearly when it is missing), so keep that line out of users' output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

from admissable_jax.config import TrainConfig  # noqa: E402
from admissable_jax.envs import make_env  # noqa: E402
from admissable_jax.missingness import candidate_sets, mask_observation  # noqa: E402
from admissable_jax.scoring import MissingnessScores, score_missingness  # noqa: E402



def __getattr__(name: str):
    """``train_fn`` and ``TrainResult`` live in :mod:`admissable_jax.train`, imported on first
    use, so that ``python -m admissable_jax.train`` does not import its own module twice."""
    if name in ("train_fn", "TrainResult"):
        from admissable_jax import train

        return getattr(train, name)
    raise AttributeError(f"module 'admissable_jax' has no attribute {name!r}")


__all__ = [
    "MissingnessScores",
    "TrainConfig",
    "TrainResult",
    "candidate_sets",
    "make_env",
    "mask_observation",
    "score_missingness",
    "train_fn",
]
