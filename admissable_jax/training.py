"""The training loop's pure core: one training-state pytree and functions of it.

An iteration steps all ``num_envs`` environments once (each observing its state masked by
its own missing set u), writes the transitions to the replay buffer, starts new episodes
where one ended (drawing a fresh u ~ p_miss for each, paper §3), and takes
``num_envs · utd`` SAC gradient steps once ``learning_starts`` env steps are collected.
``run_chunk`` scans iterations on the device; ``score_and_update`` scores every u in one
batched rollout and applies the adversary's update. Both are pure functions of
:class:`TrainState`, so they jit, and vmap over seeds or over (seed, mode) pairs: the mode
is data (``adversarial``, ``masking``), not code. The trainer reads a frozen
:class:`~admissable_jax.run_spec.RunSpec`, never the user's config.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from admissable_jax import replay
from admissable_jax.adversary import update_p_miss, uniform_p_miss
from admissable_jax.agent import SAC, SACBatch, SACState
from admissable_jax.envs import EnvState, reset_where_done
from admissable_jax.missingness import candidate_sets, mask_observation, sample_set_indices
from admissable_jax.run_spec import RunSpec
from admissable_jax.scoring import MissingnessScores, score_missingness


@struct.dataclass
class TrainState:
    sac: SACState
    buffer: replay.ReplayBuffer
    env_states: EnvState  # batched over num_envs
    set_index: jax.Array  # (num_envs,) each env's current missing set (index into U)
    p_miss: jax.Array  # (|U|,)
    adversarial: jax.Array  # () bool: update p_miss from the scores
    masking: jax.Array  # () bool: False in mode "none" (nothing hidden in training)
    rng: jax.Array  # raw uint32 key
    env_steps: jax.Array  # () int32, over all envs
    grad_steps: jax.Array  # () int32


class Trainer:
    """Static parts of a run (env, agent, candidate sets, sizes) and its pure functions."""

    def __init__(self, env, spec: RunSpec):
        self.env = env
        self.spec = spec
        self.hidden_sets = jnp.asarray(candidate_sets(env.observation_size, spec.k, spec.include_empty_set))
        self.num_sets = int(self.hidden_sets.shape[0])
        self.agent = SAC(2 * env.observation_size, env.action_low, env.action_high, spec.sac)

    # --- construction -------------------------------------------------------------------
    def init(self, seed: jax.Array, mode_adversarial: jax.Array, mode_masking: jax.Array) -> TrainState:
        """A fresh run. ``seed`` is an int (traced: vmap over seeds works)."""
        rng = jax.random.PRNGKey(seed)
        rng, agent_rng, env_rng, set_rng = jax.random.split(rng, 4)
        p_miss = uniform_p_miss(self.num_sets)
        return TrainState(
            sac=self.agent.init(agent_rng),
            buffer=replay.init_buffer(self.spec.buffer_capacity, self.env.observation_size, self.env.action_size),
            env_states=jax.vmap(self.env.reset)(jax.random.split(env_rng, self.spec.num_envs)),
            set_index=sample_set_indices(set_rng, p_miss, (self.spec.num_envs,)),
            p_miss=p_miss,
            adversarial=jnp.asarray(mode_adversarial, bool),
            masking=jnp.asarray(mode_masking, bool),
            rng=rng,
            env_steps=jnp.zeros((), jnp.int32),
            grad_steps=jnp.zeros((), jnp.int32),
        )

    # --- pieces -------------------------------------------------------------------------
    def hidden_rows(self, state: TrainState, set_index: jax.Array) -> jax.Array:
        """The 0/1 rows hidden for these set indices (all zeros when not masking)."""
        return self.hidden_sets[set_index] * state.masking.astype(jnp.float32)

    def policy(self, actor_params, masked_obs: jax.Array) -> jax.Array:
        """Deterministic policy on one masked observation, as scoring runs it."""
        return self.agent.deterministic_action(actor_params, masked_obs)

    def _act(self, state: TrainState, rng: jax.Array) -> jax.Array:
        random_rng, policy_rng = jax.random.split(rng)
        masked = mask_observation(state.env_states.obs, self.hidden_rows(state, state.set_index))
        policy_action, _ = self.agent.sample_action(state.sac.actor_params, masked, policy_rng)
        random_action = jax.random.uniform(
            random_rng, policy_action.shape, minval=self.env.action_low, maxval=self.env.action_high
        )
        return jnp.where(state.env_steps < self.spec.learning_starts, random_action, policy_action)

    def _learn(self, state: TrainState, rng: jax.Array) -> tuple[SACState, dict[str, jax.Array]]:
        # All minibatches are drawn before the learning_starts branch, so the branch's operands
        # are the SAC state and (n, batch) transitions, never the whole replay buffer.
        sample_keys, update_keys = jnp.moveaxis(
            jax.vmap(jax.random.split)(jax.random.split(rng, self.spec.updates_per_iteration)), 1, 0
        )
        batches = jax.vmap(lambda key: self._minibatch(state, key))(sample_keys)

        def one_update(sac_state, batch_and_key):
            return self.agent.update(sac_state, *batch_and_key)

        def updates(sac_state):
            sac_state, metrics = jax.lax.scan(one_update, sac_state, (batches, update_keys))
            return sac_state, jax.tree.map(jnp.mean, metrics)

        def skip(sac_state):
            _, metrics = jax.eval_shape(updates, sac_state)
            return sac_state, jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype), metrics)

        # As SB3: learn once more than learning_starts steps are collected.
        return jax.lax.cond(self._learning(state), updates, skip, state.sac)

    def _minibatch(self, state: TrainState, rng: jax.Array) -> SACBatch:
        """A uniform replay minibatch, masked with each transition's own missing set."""
        batch = replay.sample(state.buffer, rng, self.spec.sac.batch_size)
        hidden = self.hidden_rows(state, batch.set_index)
        return SACBatch(
            obs=mask_observation(batch.obs, hidden),
            action=batch.action,
            reward=batch.reward,
            next_obs=mask_observation(batch.next_obs, hidden),
            terminated=batch.terminated,
        )

    def _learning(self, state: TrainState) -> jax.Array:
        return state.env_steps > self.spec.learning_starts

    # --- the iteration ------------------------------------------------------------------
    def iteration(self, state: TrainState, _=None) -> tuple[TrainState, dict[str, jax.Array]]:
        rng, act_rng, reset_rng, set_rng, learn_rng = jax.random.split(state.rng, 5)
        actions = self._act(state, act_rng)
        stepped = jax.vmap(self.env.step)(state.env_states, actions)
        buffer = replay.insert(
            state.buffer,
            replay.Transitions(
                obs=state.env_states.obs,
                set_index=state.set_index,
                action=actions,
                reward=stepped.reward,
                next_obs=stepped.obs,
                terminated=stepped.terminated,
            ),
        )
        done = stepped.done
        env_states = jax.vmap(reset_where_done, (None, 0, 0))(
            self.env, stepped, jax.random.split(reset_rng, self.spec.num_envs)
        )
        new_sets = sample_set_indices(set_rng, state.p_miss, (self.spec.num_envs,))
        state = state.replace(
            buffer=buffer,
            env_states=env_states,
            set_index=jnp.where(done, new_sets, state.set_index),
            env_steps=state.env_steps + self.spec.num_envs,
            rng=rng,
        )
        sac_state, learn_metrics = self._learn(state, learn_rng)
        learned = self._learning(state)
        state = state.replace(
            sac=sac_state,
            grad_steps=state.grad_steps + learned.astype(jnp.int32) * self.spec.updates_per_iteration,
        )
        finished_returns = stepped.episode_metrics["return"]
        metrics = {
            **learn_metrics,
            "learned": learned,
            "episodes": done.sum(),
            "episode_return_sum": jnp.sum(jnp.where(done, finished_returns, 0.0)),
            "episode_length_sum": jnp.sum(jnp.where(done, stepped.step_count, 0)),
            "capacity_exceeded": self.env.capacity_exceeded(stepped),
        }
        return state, metrics

    def run_chunk(self, state: TrainState, num_iterations: int) -> tuple[TrainState, dict[str, jax.Array]]:
        """``num_iterations`` iterations on the device; per-iteration metrics stacked."""
        return jax.lax.scan(self.iteration, state, None, length=num_iterations)

    def critic_values(self, critic_params, masked_obs: jax.Array, action: jax.Array) -> jax.Array:
        """Both critics' Q on one masked observation and action: (2,)."""
        return self.agent.critic.apply(critic_params, masked_obs, action)

    def score_and_update(self, state: TrainState) -> tuple[TrainState, MissingnessScores]:
        """Score every u (N = ``score_episodes`` episodes each, by the spec's estimator: one
        batched rollout, or the critic's estimate) and update p_miss (adversarial mode only)."""
        rng, score_rng = jax.random.split(state.rng)
        scores = score_missingness(
            self.env, self.policy, state.sac.actor_params, score_rng, self.hidden_sets, self.spec.score_episodes,
            num_slots=self.spec.score_envs, score_estimator=self.spec.score_estimator, critic_fn=self.critic_values,
            critic_params=state.sac.critic_params, score_horizon=self.spec.score_horizon, gamma=self.spec.sac.gamma,
        )
        p_miss = update_p_miss(
            state.p_miss, scores.scores, state.adversarial, self.spec.lower_bound, self.spec.epsilon
        )
        return state.replace(p_miss=p_miss, rng=rng), scores
