"""An environment's construction options: one frozen bundle, fixed for the env's life.

The env layer alone decides how physics runs: ``physics="auto"`` picks MuJoCo Warp
(``mjx.put_model(..., impl="warp")``) on an NVIDIA GPU when ``warp-lang`` is importable and
MJX's JAX implementation everywhere else. Code above :mod:`admissable_jax.envs` passes the
option through and never branches on it.
"""

from __future__ import annotations

import dataclasses
import functools

import jax

PHYSICS_CHOICES = ("auto", "jax", "warp")
CUDA_GRAPH_MODES = ("WARP", "WARP_STAGED")  # MuJoCo Warp's CUDA-graph modes under JAX (a GPU's)
WARP_GRAPH_MODES = (*CUDA_GRAPH_MODES, "NONE")  # and none
MAX_EPISODE_STEPS = 1000  # Gymnasium's TimeLimit for all four v5 envs.
DEFAULT_MAX_BATCH = 1024


@dataclasses.dataclass(frozen=True)
class EnvOptions:
    """How an env is built. All fields are validated at construction.

    Attributes:
        episode_length: the step limit after which an episode is truncated (v5: 1000;
            shorter only for tests and smoke runs).
        physics: ``"auto"``, ``"jax"`` (MJX's JAX implementation) or ``"warp"`` (MuJoCo
            Warp through MJX). ``"auto"`` resolves to warp on an NVIDIA GPU when warp-lang
            is importable, else jax; :attr:`resolved_physics` says which.
        solver_iterations, ls_iterations: override the XML's solver iterations (``None``:
            the XML's own, which Gymnasium parity needs). Faster, not Gymnasium-exact.
        max_batch: the most environments stepped at once by one compiled program, over all
            vmapped axes together (e.g. runs × envs). Warp keeps the contacts of every
            world in one shared buffer, sized from this and the model's largest possible
            contact count; a step that would exceed it stops the run with an error
            naming this setting. The JAX backend does not need it.
        terminate_when_unhealthy: Gymnasium v5's argument of the same name: ``False``
            never terminates an episode (the healthy reward still follows the health
            rules), so every episode runs to ``episode_length``; benchmarks use it to time
            the longest scoring rounds with an untrained policy.
        graph_mode: Warp only: how MuJoCo Warp's kernels run under JAX
            (``mjx.put_model(..., graph_mode=...)``): ``"WARP"`` or ``"WARP_STAGED"``
            (CUDA-graph capture modes, a GPU's only), ``None`` for MJX's default, or ``"NONE"``: no
            graph, every kernel launched from Python at every step; slow, but a check:
            on a GPU, Warp then reads its deterministic mode's buffers after each launch
            and raises where a thread outgrew them, which inside a captured graph drops
            contributions or slots without a word.
        deterministic: Warp only: MuJoCo Warp's deterministic mode (the ``mujoco-warp``
            package, :mod:`.warp_package`): atomic sums, contact slots and constraint rows
            in a fixed order, towards a GPU repeating a run bit for bit (which continuing a
            run on another machine needs, :mod:`admissable_jax.fast_forward`). ``False``:
            the GPU's own order, which may be faster. One setting per process.
        worlds_per_call: JAX physics only: the most worlds one vectorised physics call
            steps; a larger batch (every vmapped axis together: pairs × envs) is stepped in
            pieces of at most this many, one after another: the same physics world by world
            (to float rounding, where XLA vectorises a piece otherwise than the whole).
            ``0``: on a CPU, the largest power of two whose worlds' data fit 256 KiB
            (Hopper 32, Walker2d 16, Ant 8), since past about that a call costs 2.5-3× as
            much per world on the CPU we measured (``benchmarks/NOTES.md``); on an
            accelerator, one call. MuJoCo Warp always steps one flat batch.
    """

    episode_length: int = MAX_EPISODE_STEPS
    physics: str = "auto"
    solver_iterations: int | None = None
    ls_iterations: int | None = None
    max_batch: int = DEFAULT_MAX_BATCH
    terminate_when_unhealthy: bool = True
    graph_mode: str | None = None
    deterministic: bool = True
    worlds_per_call: int = 0

    def __post_init__(self) -> None:
        for name in ("episode_length", "max_batch"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if self.episode_length > MAX_EPISODE_STEPS:
            raise ValueError(f"episode_length must be <= {MAX_EPISODE_STEPS} (the v5 limit), got {self.episode_length}")
        _check_physics_choice(self.physics)
        for name in ("solver_iterations", "ls_iterations"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < 1):
                raise ValueError(f"{name} must be None or an int >= 1, got {value!r}")
        for name in ("terminate_when_unhealthy", "deterministic"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        if not isinstance(self.worlds_per_call, int) or isinstance(self.worlds_per_call, bool) or self.worlds_per_call < 0:
            raise ValueError(f"worlds_per_call must be an int >= 0 (0: from the world's size), got {self.worlds_per_call!r}")
        if self.graph_mode is not None and self.graph_mode not in WARP_GRAPH_MODES:
            raise ValueError(f"graph_mode must be None or one of {', '.join(WARP_GRAPH_MODES)}, got {self.graph_mode!r}")

    @property
    def resolved_physics(self) -> str:
        """``"jax"`` or ``"warp"``: what ``physics`` means on this machine."""
        return resolve_physics(self.physics)


def resolve_physics(physics: str) -> str:
    """``"warp"`` or ``"jax"`` for a ``physics`` choice; ValueError for an unknown choice, or
    for warp when ``warp-lang`` is not installed."""
    _check_physics_choice(physics)
    if physics == "warp" and not warp_installed():
        raise ValueError("physics=warp needs the warp-lang package (pip install warp-lang, or the 'cuda' extra)")
    if physics == "auto":
        return "warp" if _on_nvidia_gpu() and warp_installed() else "jax"
    return physics


def _check_physics_choice(physics: str) -> None:
    if physics not in PHYSICS_CHOICES:
        raise ValueError(f"physics must be one of {', '.join(PHYSICS_CHOICES)}, got {physics!r}")


@functools.cache
def warp_installed() -> bool:
    """Whether warp-lang imports: MJX's own test (``mujoco.mjx.warp.WARP_INSTALLED``), made
    without importing MJX, so that validating ``physics=warp`` loads no physics."""
    try:
        import warp  # noqa: F401
    except (ImportError, RuntimeError):
        return False
    return True


def _on_nvidia_gpu() -> bool:
    """Whether JAX's default device is a CUDA GPU (as MJX itself tests for Warp)."""
    try:
        return jax.devices()[0] in jax.devices("cuda")
    except RuntimeError:  # no CUDA backend
        return False
