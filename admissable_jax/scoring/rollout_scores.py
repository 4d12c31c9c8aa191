"""Adversarial scores a_u for every candidate set, in one batched rollout (paper §3): the
``rollout`` estimator of :func:`~admissable_jax.scoring.score_missingness`.

a_u = v̂_u^π(s_0): the mean undiscounted return of N episodes of the deterministic policy
with the features in u hidden, run to termination or the env's step limit. All
(|U| + 1) · N episodes (the +1 is the clean case, nothing hidden) run in one jitted
rollout: a ``lax.while_loop`` over time that steps a pool of ``num_slots`` environments
at once (vmapped) and stops once every episode is done (vmapped rollouts, once every one
of theirs is: :func:`~admissable_jax.branching.while_any`). With fewer slots than episodes, a
slot whose episode ends starts the next unstarted one at the following step, so the pool
stays full of live episodes instead of stepping finished ones until the longest ends.
Episode i starts from the same initial state for every u (common random numbers), so
differences between sets are not reset noise; which slot runs an episode does not change
its return.

On a GPU, XLA runs a ``while_loop`` whose condition depends on data by copying the
condition to the host at every iteration and waiting for it, so the host cannot queue the
next steps' kernels ahead of the device. ``steps_per_check`` > 1 runs that many steps per
check (a ``scan`` inside the loop): steps taken after every episode has ended change no
result (``loop_steps`` counts only steps with an episode running), at most
``steps_per_check`` − 1 extra steps per round.
"""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple, Sequence

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from admissable_jax.branching import while_any
from admissable_jax.method import fail_steps, hidden_from_step, spread_fail_steps
from admissable_jax.missingness import mask_observation

PolicyFn = Callable[[Any, jax.Array], jax.Array]  # (params, masked_obs (2·d,)) -> action


@struct.dataclass
class MissingnessScores:
    """Scores of all candidate sets (rows of ``hidden_sets``) and of the clean case."""

    scores: jax.Array  # (|U|,) a_u, mean return with u hidden
    clean_score: jax.Array  # () mean return with nothing hidden
    returns: jax.Array  # (|U| + 1, N) per-episode returns; last row is the clean case
    lengths: jax.Array  # (|U| + 1, N) episode lengths
    loop_steps: jax.Array  # () batched steps the rollout took (each steps every slot)
    capacity_exceeded: jax.Array  # () bool: the env's physics ran out of a fixed buffer

    @property
    def min_score(self) -> jax.Array:
        return jnp.min(self.scores)

    @property
    def argmin(self) -> jax.Array:
        return jnp.argmin(self.scores)

    @property
    def mean_score(self) -> jax.Array:
        """The average case beside the worst: a_u's mean over the scored sets."""
        return jnp.mean(self.scores)


def score_by_rollout(
    env,
    policy_fn: PolicyFn,
    params: Any,
    rng: jax.Array,
    hidden_sets: jax.Array,
    n_episodes: int = 10,
    max_steps: int | None = None,
    num_slots: int | None = None,
    steps_per_check: int = 1,
    fail_at: int | str | Sequence[int] = 0,
) -> MissingnessScores:
    """Score every u in ``hidden_sets`` ((|U|, d) 0/1 rows) and the clean case.

    ``policy_fn(params, masked_obs) -> action`` may be any JAX function of the 2·d masked
    observation (our SAC actor's mean action, or a hand-written controller). ``max_steps``
    defaults to the env's limit (1000). ``num_slots`` is how many envs are stepped at once
    (default: all (|U| + 1) · N episodes, or the env's ``max_batch`` if that is smaller;
    never more than the episodes, so ``min(num_slots, (|U| + 1) · N)`` is what must fit
    ``max_batch``). Fewer trades loop steps for a smaller batch, which pays where a step's
    cost grows with the batch, as on a CPU. ``steps_per_check``: steps between checks
    whether any episode still runs (module docstring). ``fail_at``: the env step of each
    episode at which u's sensors fail, seen until then (0: hidden from the start, the paper's
    a_u; :func:`~admissable_jax.method.hidden_from_step`); several steps (a list or comma
    text) split each set's N episodes evenly over them, episode i failing at the (i mod m)-th
    of the m steps, so a_u is the mean of the steps' a_u
    (:func:`~admissable_jax.method.spread_fail_steps`; N must be a multiple of m). Jit-able
    with ``env``, ``policy_fn``, ``n_episodes``, ``max_steps``, ``num_slots``,
    ``steps_per_check`` and ``fail_at`` static. :class:`RolloutInSegments` runs the same
    rollout from the host, telling the episodes finished as it goes.
    """
    hidden_sets = jnp.asarray(hidden_sets, jnp.float32)
    rollout = rollout_program(env, policy_fn, hidden_sets.shape, n_episodes, max_steps, num_slots, steps_per_check,
                              fail_at)
    carry, operands = rollout.start(rng, hidden_sets)
    return rollout.finish(rollout.advance(carry, params, operands))


class RolloutProgram(NamedTuple):
    """One scoring rollout in three parts (:func:`rollout_program`)."""

    start: Callable[[jax.Array, jax.Array], tuple[dict, tuple]]  # (rng, hidden_sets) -> (carry, operands)
    advance: Callable[..., dict]  # (carry, params, operands, until=None) -> carry: steps while any episode runs
    finish: Callable[[dict], MissingnessScores]  # carry -> the scores


def rollout_program(env, policy_fn: PolicyFn, sets_shape: tuple[int, int], n_episodes: int = 10,
                    max_steps: int | None = None, num_slots: int | None = None, steps_per_check: int = 1,
                    fail_at: int | str | Sequence[int] = 0) -> RolloutProgram:
    """:func:`score_by_rollout`'s rollout of ``sets_shape`` = (|U|, d) sets, its arguments
    checked: ``start`` the slots' first episodes, ``advance`` the loop (with ``until``, only
    while ``loop_steps`` < ``until``: a segment), ``finish`` the scores from the last carry."""
    if steps_per_check < 1:
        raise ValueError(f"steps_per_check must be >= 1, got {steps_per_check}")
    num_sets, num_features = sets_shape
    chex.assert_equal(num_features, env.observation_size)
    max_steps = env.max_episode_steps if max_steps is None else max_steps
    if max_steps < 1:  # (at 0, every episode would still take its first step)
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    episode_fail_steps = spread_fail_steps(fail_at, n_episodes, max_steps)  # of the N start states
    num_rows = num_sets + 1
    num_episodes = num_rows * n_episodes  # episode e: set row e // N, initial state e % N
    max_batch = env.options.max_batch
    slots_asked = num_slots
    num_slots = min(num_episodes, max_batch) if num_slots is None else max(1, min(num_slots, num_episodes))
    if num_slots > max_batch:  # the envs stepped at once (slots beyond the episodes never run)
        raise ValueError(f"num_slots={slots_asked} steps {num_slots} envs at once, more than the env's "
                         f"max_batch={max_batch}; build the env with a larger max_batch or give fewer slots")
    policy = jax.vmap(policy_fn, in_axes=(None, 0))

    def initial_states(initial, episode: jax.Array):
        return jax.tree.map(lambda x: x[episode % n_episodes], initial)

    def refilled(states, refill, episode, initial):
        fresh = initial_states(initial, jnp.minimum(episode, num_episodes - 1))
        return jax.tree.map(lambda new, old: jnp.where(_rows(refill, old), new, old), fresh, states)

    def cond(carry, *_):
        return jnp.any(carry["alive"])

    def step(carry, params, episode_hidden, initial):
        states, episode, alive = carry["states"], carry["episode"], carry["alive"]
        hidden = episode_hidden[episode]
        if any(episode_fail_steps):  # (at 0 the program is the paper's, as training compiles it)
            hidden = hidden_from_step(hidden, states.step_count,
                                      jnp.asarray(episode_fail_steps, jnp.int32)[episode % n_episodes])
        with jax.named_scope("score_policy"):
            actions = policy(params, mask_observation(states.obs, hidden))
        with jax.named_scope("score_env_step"):
            states = jax.vmap(env.step)(states, actions)
        finished = alive & (states.terminated | (states.step_count >= max_steps))
        record_at = jnp.where(finished, episode, num_episodes)  # out of range: dropped
        returns = carry["returns"].at[record_at].set(states.episode_metrics["return"], mode="drop")
        lengths = carry["lengths"].at[record_at].set(states.step_count, mode="drop")
        # Finished slots take the next unstarted episodes, in slot order.
        next_episode = carry["next_episode"] + jnp.cumsum(finished) - 1
        refill = finished & (next_episode < num_episodes)
        if num_slots < num_episodes:  # else every episode started at step 0: nothing to refill
            episode = jnp.where(refill, next_episode, episode)
            states = jax.lax.cond(jnp.any(refill), refilled, lambda states, *_: states, states, refill, episode, initial)
        return {
            "states": states, "episode": episode, "alive": jnp.where(finished, refill, alive),
            "next_episode": carry["next_episode"] + finished.sum(), "returns": returns,
            "lengths": lengths, "loop_steps": carry["loop_steps"] + jnp.any(alive),
            "capacity_exceeded": carry["capacity_exceeded"] | (jnp.any(alive) & env.capacity_exceeded(states)),
        }

    def body(carry, *operands):
        if steps_per_check == 1:
            carry = step(carry, *operands)
        else:
            carry = jax.lax.scan(lambda carry, _: (step(carry, *operands), None), carry, None, length=steps_per_check)[0]
        return carry

    def start(rng: jax.Array, hidden_sets: jax.Array) -> tuple[dict, tuple]:
        episode_hidden = jnp.repeat(jnp.concatenate([hidden_sets, jnp.zeros((1, num_features))]), n_episodes, axis=0)
        initial = jax.vmap(env.reset)(jax.random.split(rng, n_episodes))
        slots = jnp.arange(num_slots)
        carry = {
            "states": initial_states(initial, slots), "episode": slots, "alive": jnp.ones(num_slots, bool),
            "next_episode": jnp.asarray(num_slots, jnp.int32), "returns": jnp.zeros(num_episodes),
            "lengths": jnp.zeros(num_episodes, jnp.int32), "loop_steps": jnp.zeros((), jnp.int32),
            "capacity_exceeded": jnp.zeros((), bool),
        }
        return carry, (episode_hidden, initial)

    def advance(carry: dict, params: Any, operands: tuple, until: jax.Array | None = None) -> dict:
        # A finished rollout's steps change none of its results (nothing is alive), so vmapped
        # rollouts (an experiment's pairs, where a batched step costs about the same for any
        # batch; on a CPU the host loop scores them in turn) step together while any runs: no
        # per-pair select of the carry, which would hand Warp's in-place step a copy of every field.
        if until is None:
            return while_any(cond, body, carry, params, *operands)
        return while_any(lambda carry, until, *_: cond(carry) & (carry["loop_steps"] < until),
                         lambda carry, until, *rest: body(carry, *rest), carry, until, params, *operands)

    def finish(carry: dict) -> MissingnessScores:
        returns = carry["returns"].reshape(num_rows, n_episodes)
        lengths = carry["lengths"].reshape(num_rows, n_episodes)
        means = returns.mean(axis=1)
        return MissingnessScores(
            scores=means[:-1], clean_score=means[-1], returns=returns, lengths=lengths,
            loop_steps=carry["loop_steps"], capacity_exceeded=carry["capacity_exceeded"],
        )

    return RolloutProgram(start, advance, finish)


# Loop steps per program call of a rollout run from the host: a Hopper scoring pool of 32
# slots stepped 35 a second on a 2-core CPU (a segment: about half a second); on an H100 the
# bare Warp Hopper step alone takes 5.3 ms, so under 200.
SEGMENT_LOOP_STEPS = 20


@functools.partial(jax.jit, static_argnums=range(9))
def _rollout_part(part: str, env, policy_fn, sets_shape, n_episodes, max_steps, num_slots, steps_per_check, fail_at,
                  *arguments):
    """One part (``start``, ``advance`` or ``finish``) of :func:`rollout_program`'s rollout,
    compiled on its own; ``part`` and the rollout's arguments static."""
    rollout = rollout_program(env, policy_fn, sets_shape, n_episodes, max_steps, num_slots, steps_per_check, fail_at)
    return getattr(rollout, part)(*arguments)


class RolloutInSegments:
    """:func:`score_by_rollout`'s rollout run from the host: the start states, then segments
    of at most ``segment`` loop steps, each a call of one compiled program, telling
    ``progress(finished)`` the episodes finished after each, then the scores; the same
    steps, so the same scores (to float rounding, where XLA fuses the programs otherwise).

    Why not one program that reports from inside: JAX keeps no program with a host callback
    in its persistent compilation cache, so every audit compiled its rollout anew (a Hopper
    audit of 5 episodes per set on a 2-core CPU: 34 s each time; 17 s once cached). These
    programs are compiled once per env, policy function, settings and sets' shape, by
    ``compile`` (a ``jax.stages.Lowered`` -> its compiled program), and cached on disk.
    Arguments as :func:`score_by_rollout`'s; ``params``, ``rng`` and ``hidden_sets`` here
    only give the shapes the programs compile for."""

    def __init__(self, env, policy_fn: PolicyFn, params: Any, rng: jax.Array, hidden_sets: jax.Array,
                 n_episodes: int = 10, max_steps: int | None = None, num_slots: int | None = None,
                 steps_per_check: int = 1, fail_at: int | str | Sequence[int] = 0, segment: int = SEGMENT_LOOP_STEPS,
                 compile: Callable[[Any], Any] = lambda lowered: lowered.compile()):
        hidden_sets = jnp.asarray(hidden_sets, jnp.float32)
        static = (env, policy_fn, tuple(hidden_sets.shape), int(n_episodes), max_steps, num_slots, steps_per_check,
                  fail_steps(fail_at))
        start = _rollout_part.lower("start", *static, rng, hidden_sets)
        carry, operands = start.out_info
        until = jax.ShapeDtypeStruct((), jnp.int32)
        self.segment, self.num_slots = segment, carry["episode"].shape[0]
        self._start = compile(start)
        self._advance = compile(_rollout_part.lower("advance", *static, carry, params, operands, until))
        self._finish = compile(_rollout_part.lower("finish", *static, carry))

    def __call__(self, params: Any, rng: jax.Array, hidden_sets: jax.Array,
                 progress: Callable[[int], None]) -> MissingnessScores:
        """The scores of ``hidden_sets`` under ``params`` from ``rng``'s start states."""
        carry, operands = self._start(rng, jnp.asarray(hidden_sets, jnp.float32))
        while True:
            carry = self._advance(carry, params, operands, carry["loop_steps"] + self.segment)
            progress(int(carry["next_episode"]) - self.num_slots)  # each finished slot moved it on by one
            if not np.any(carry["alive"]):
                return self._finish(carry)


def _rows(mask: jax.Array, like: jax.Array) -> jax.Array:
    """``mask`` (B,) broadcast against a batched leaf (B, ...)."""
    return mask.reshape(mask.shape + (1,) * (like.ndim - 1))
