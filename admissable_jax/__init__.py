"""admissable_jax: training RL agents against adversarial missingness, in JAX on MJX."""

import contextlib
import io

# MJX's optional Warp backend prints an import failure when NVIDIA Warp is absent; we use
# the JAX backend only, so keep that line out of users' output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

from admissable_jax.envs import make_env  # noqa: E402

__all__ = ["make_env"]
