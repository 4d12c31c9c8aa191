"""admissable_jax: training RL agents against adversarial missingness, in JAX on MJX.

The public names below are imported on first use, so that ``admissable_jax.wrappers`` (NumPy
and Gymnasium only) imports no JAX, and ``python -m admissable_jax.train`` does not import
its own module twice.
"""

import importlib
import importlib.metadata
import os

# XLA:CPU compiles our MJX and SAC programs about a third faster with its older elemental
# emitters than with its fusion emitters, and runs them as fast (benchmarks/xla_cpu_compile.py,
# record xla_cpu_compile.jsonl); on a CPU, compiling is most of a short run. XLA reads the flag
# when JAX first starts a backend, so it is set here, before anything of ours touches JAX; a
# setting of the same flag in XLA_FLAGS wins. GPU backends ignore it, but jaxlib 0.11 no
# longer knows it and aborts on it, so it is set only for the jaxlib 0.10 we pin.
CPU_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"


def _jaxlib_knows_compile_flag() -> bool:
    try:
        return importlib.metadata.version("jaxlib").startswith("0.10.")
    except importlib.metadata.PackageNotFoundError:
        return False


def default_xla_flag(flag: str) -> None:
    """Add ``flag`` (``--name=value``) to XLA_FLAGS unless XLA_FLAGS already sets that name:
    a setting given there wins. XLA reads XLA_FLAGS once, when JAX starts a backend."""
    name = flag.split("=")[0]
    if name not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()


if _jaxlib_knows_compile_flag():
    default_xla_flag(CPU_COMPILE_FLAG)

_PUBLIC = {
    "TrainConfig": "admissable_jax.config",
    "make_env": "admissable_jax.envs",
    "candidate_sets": "admissable_jax.missingness",
    "mask_observation": "admissable_jax.missingness",
    "MissingnessScores": "admissable_jax.scoring",
    "score_missingness": "admissable_jax.scoring",
    "train_fn": "admissable_jax.train",
    "TrainResult": "admissable_jax.train",
}


def __getattr__(name: str):
    if name in _PUBLIC:
        return getattr(importlib.import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module 'admissable_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])


__all__ = sorted(_PUBLIC)
