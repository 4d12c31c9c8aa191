"""``score_missingness``: every set's a_u by the chosen estimator, one call for all three.

- ``rollout`` (the default, the paper's): N whole episodes per set in one batched rollout
  (:func:`~admissable_jax.scoring.rollout_scores.score_by_rollout`).
- ``critic`` and ``horizon``: the trained critic's discounted value, alone or after
  ``score_horizon`` physics steps
  (:func:`~admissable_jax.scoring.value_estimates.estimate_scores`; its docstring defines both
  and says how p_miss reads discounted values).
"""

from __future__ import annotations

import functools
import numbers
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax.method import fail_steps, spread_fail_steps
from admissable_jax.missingness import check_zero_one
from admissable_jax.scoring.rollout_scores import MissingnessScores, PolicyFn, RolloutInSegments, score_by_rollout
from admissable_jax.scoring.value_estimates import CriticFn, estimate_scores

SCORE_ESTIMATORS = ("rollout", "critic", "horizon")


def score_missingness(
    env,
    policy_fn: PolicyFn,
    params: Any,
    rng: jax.Array,
    hidden_sets: jax.Array,
    n_episodes: int = 10,
    max_steps: int | None = None,
    num_slots: int | None = None,
    *,
    steps_per_check: int = 1,
    score_estimator: str = "rollout",
    critic_fn: CriticFn | None = None,
    critic_params: Any = None,
    score_horizon: int = 100,
    gamma: float = 0.99,
    progress: Callable[[int], None] | None = None,
    fail_at: int | str | Sequence[int] = 0,
) -> MissingnessScores:
    """Score every u in ``hidden_sets`` ((|U|, d) 0/1 rows) and the clean case, N =
    ``n_episodes`` from the same N start states, by ``score_estimator``. ``max_steps``,
    ``num_slots`` and ``steps_per_check`` concern ``rollout`` (see ``score_by_rollout``); ``critic_fn(critic_params,
    masked_obs, action) -> (2,)`` twin Q, ``score_horizon`` (H) and ``gamma`` the other two.
    ``progress(finished)``: the ``rollout``'s episodes finished so far, told between its
    segments (:class:`~admissable_jax.scoring.rollout_scores.RolloutInSegments`: programs the
    host runs in turn, of at most 20 loop steps each, so not inside a caller's jit).
    ``fail_at`` (``rollout`` only): the env step of each episode at which u's sensors fail,
    seen until then; 0, the paper's a_u, hides them from the start; several steps (a list
    or comma text) split each set's N episodes evenly over them (N a multiple of their
    number; see ``score_by_rollout``).
    Called directly it runs as one program, compiled once per env, function, setting and
    shape of ``hidden_sets`` (op by op, each call compiled its rollout again and each eager
    op of its start states once); inside a caller's jit it is part of the caller's program."""
    if score_estimator not in SCORE_ESTIMATORS:
        raise ValueError(f"score_estimator must be one of {', '.join(SCORE_ESTIMATORS)}, got {score_estimator!r}")
    if score_estimator != "rollout" and critic_fn is None:
        raise ValueError(f"score_estimator={score_estimator} needs the critic (critic_fn and critic_params)")
    if progress is not None and score_estimator == "rollout":
        rollout = rollout_in_segments(env, policy_fn, params, rng, hidden_sets, n_episodes, max_steps, num_slots,
                                      steps_per_check=steps_per_check, fail_at=fail_at)
        return rollout(params, rng, hidden_sets, progress)
    fail_at = _checked(env, policy_fn, params, rng, hidden_sets, n_episodes, fail_at)
    if fail_at != (0,) and score_estimator != "rollout":
        raise ValueError(f"fail_at={','.join(map(str, fail_at))} needs score_estimator=rollout: the critic values each "
                         f"start with u hidden from it, not a sensor that fails later")
    return _scores(env, policy_fn, params, rng, hidden_sets, int(n_episodes), max_steps, num_slots, steps_per_check,
                   score_estimator, critic_fn, critic_params, score_horizon, gamma, fail_at)


def rollout_in_segments(env, policy_fn: PolicyFn, params: Any, rng: jax.Array, hidden_sets: jax.Array,
                        n_episodes: int = 10, max_steps: int | None = None, num_slots: int | None = None, *,
                        steps_per_check: int = 1, fail_at: int | str | Sequence[int] = 0,
                        compile: Callable[[Any], Any] = lambda lowered: lowered.compile()) -> RolloutInSegments:
    """The ``rollout`` estimator's programs, to run from the host with a progress report
    (:class:`~admissable_jax.scoring.rollout_scores.RolloutInSegments`), compiled by
    ``compile``; its arguments checked as :func:`score_missingness` checks them. Not inside
    a caller's jit: ValueError in one line."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves((params, rng, hidden_sets))):
        raise ValueError("score_missingness with progress= runs its rollout from the host, in segments: call it "
                         "outside jit (or without progress=)")
    fail_at = _checked(env, policy_fn, params, rng, hidden_sets, n_episodes, fail_at)
    return RolloutInSegments(env, policy_fn, params, rng, hidden_sets, int(n_episodes), max_steps, num_slots,
                             steps_per_check, fail_at, compile=compile)


def _checked(env, policy_fn: PolicyFn, params: Any, rng: jax.Array, hidden_sets: jax.Array, n_episodes: int,
             fail_at: int | str | Sequence[int]) -> tuple[int, ...]:
    """The arguments every estimator takes, checked (one line each); ``fail_at``'s steps."""
    _check_arguments(env, hidden_sets, n_episodes)
    _check_key(rng)
    _check_policy(env, policy_fn, params)
    fail_at = fail_steps(fail_at)  # (and against the episodes' length where the rollout knows it)
    spread_fail_steps(fail_at, n_episodes)  # ValueError where the steps would split the N episodes unevenly
    return fail_at


@functools.partial(jax.jit, static_argnums=(0, 1, 5, 6, 7, 8, 9, 10, 12, 13, 14))
def _scores(env, policy_fn: PolicyFn, params: Any, rng: jax.Array, hidden_sets: jax.Array, n_episodes: int,
            max_steps: int | None, num_slots: int | None, steps_per_check: int, score_estimator: str,
            critic_fn: CriticFn | None, critic_params: Any, score_horizon: int, gamma: float,
            fail_at: tuple[int, ...]) -> MissingnessScores:
    """:func:`score_missingness` once its arguments are checked (everything but the
    parameters, the key and the sets static)."""
    if score_estimator == "rollout":
        return score_by_rollout(env, policy_fn, params, rng, hidden_sets, n_episodes, max_steps, num_slots,
                                steps_per_check, fail_at)
    horizon = score_horizon if score_estimator == "horizon" else 0
    return estimate_scores(env, policy_fn, params, critic_fn, critic_params, rng, hidden_sets, n_episodes, horizon, gamma)


def _check_policy(env, policy_fn: PolicyFn, params: Any) -> None:
    """ValueError in one line for a ``policy_fn`` whose action for one masked observation
    (2·d) is not one of the env's actions, ``(action_size,)``: found by tracing it (nothing
    runs), where the rollout would fail deep inside with a broadcasting error."""
    masked_obs = jax.ShapeDtypeStruct((2 * env.observation_size,), jnp.float32)
    action = jax.eval_shape(policy_fn, params, masked_obs)
    if getattr(action, "shape", None) != (env.action_size,):
        returned = jax.tree.map(lambda leaf: tuple(leaf.shape), action)
        raise ValueError(f"policy_fn(params, masked_obs) must return one action of shape ({env.action_size},) "
                         f"for a masked observation of shape ({2 * env.observation_size},), got {returned}")


def _check_key(rng) -> None:
    """TypeError in one line for an ``rng`` that is no JAX PRNG key (a seed given as an int,
    where JAX would say "invalid PRNG key data")."""
    dtype, shape = getattr(rng, "dtype", None), np.shape(rng)
    typed = dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) and shape == ()
    raw = dtype == np.uint32 and shape == (2,)
    if not (typed or raw):
        given = f"{type(rng).__name__} {rng!r}" if dtype is None else f"an array of {dtype} and shape {shape}"
        raise TypeError(f"rng must be one JAX PRNG key (jax.random.key(seed)), got {given}")


def _check_arguments(env, hidden_sets, n_episodes: int) -> None:
    """ValueError in one line for sets that are not (|U|, d) 0/1 rows (their values are
    checked where they are concrete, not under jit) or for N < 1; TypeError for an env that
    is none (its name, say)."""
    if not all(hasattr(env, name) for name in ("observation_size", "action_size", "reset", "step")):
        raise TypeError(f"env must be an env, as make_env builds it, got {env!r}"
                        + (f": make_env({env!r})" if isinstance(env, str) else ""))
    if not isinstance(n_episodes, numbers.Integral) or isinstance(n_episodes, bool) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an int >= 1, got {n_episodes!r}")
    d = env.observation_size
    shape = np.shape(hidden_sets)
    if len(shape) != 2 or shape[1] != d:
        raise ValueError(f"hidden_sets must be (|U|, d = {d}) 0/1 rows, one per set, got shape {shape}")
    check_zero_one(hidden_sets, "hidden_sets")

