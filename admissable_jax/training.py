"""The training loop's pure core: one training-state pytree and functions of it.

An iteration steps all ``num_envs`` environments once (each observing its state masked by
its own missing set u), writes the transitions to the replay buffer, starts new episodes
where one ended (drawing a fresh u ~ p_miss for each, paper §3), and takes
``num_envs · utd`` SAC gradient steps once ``learning_starts`` env steps are collected.
Beyond the paper, ``fail_at`` lets u's sensors fail mid-episode: each episode also draws the
env step from which u is hidden (every feature seen before it); scoring still hides u from
the start, so a_u, p_miss and the headline min_u a_u are the paper's, unless
``score_fail_at`` splits each set's N scoring episodes over failure steps too (then the
adversary scores what training meets; the rollout alone: a pool's critic ranker values starts).
``run_chunk`` scans iterations on the device; ``score_and_update`` scores every u in one
batched rollout and applies the adversary's update.

The candidate sets U are all C(d, k) sets of k features (of 1 .. k features with
``up_to_k``, the paper's |u| <= k), and ``set_index`` indexes them in the order of
:class:`~admissable_jax.method.SetNumbering`, which finds a set's row from its index (and
back) without listing U where U is too big to list. With ``pool_size`` P > 0 (where U is too
big to score every round: Ant at k = 2 has 5,460 sets, at k = 3 187,460) the adversary
works on a pool instead: every scoring round a beam search of width P
(:func:`~admissable_jax.scoring.beam_search_worst_sets`), ranked by the cheap
``pool_ranker`` (the critic by default), picks the P sets of U it finds worst, fresh each
round; only these are scored by ``score_estimator`` and p_miss is over them. An adversarial
episode draws its set from the pool by p_miss, or with probability ``pool_explore`` a
uniformly random set of all U, so the agent (and the critic that ranks the next search)
keeps meeting sets outside the pool. Uniform mode draws uniformly from all U. Both are pure functions of
:class:`TrainState`, so they jit, and vmap over seeds or over (seed, mode) pairs: the mode
is data (``adversarial``, ``masking``, ``greedy``), not code, and so is the adversary's lower bound l
(``lower_bound``), so that one program can sweep it. The trainer reads a frozen
:class:`~admissable_jax.run_spec.RunSpec`, never the user's config.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from admissable_jax import replay
from admissable_jax.adversary import update_p_miss, uniform_p_miss
from admissable_jax.agent import SAC, SACBatch, SACState
from admissable_jax.branching import lazy_cond
from admissable_jax.envs import EnvState, reset_where_done
from admissable_jax.fingerprints import tree_fingerprint
from admissable_jax.method import hidden_from_step
from admissable_jax.missingness import SetNumbering, mask_observation, sample_distinct_sets, sample_set_indices
from admissable_jax.run_spec import RunSpec
from admissable_jax.scoring import MissingnessScores, beam_search_worst_sets, score_missingness


@struct.dataclass
class TrainState:
    """Everything a run carries from one iteration to the next, as one pytree: the agent,
    its replay buffer, the envs mid-episode with each one's hidden set u, the adversary's
    p_miss, and the mode as data (``adversarial``, ``masking``, ``greedy``), so one compiled
    program trains every mode and a vmap over a leading axis trains many (seed, mode) pairs."""

    sac: SACState
    buffer: replay.ReplayBuffer
    env_states: EnvState  # batched over num_envs
    set_index: jax.Array  # (num_envs,) each env's current missing set (index into U)
    p_miss: jax.Array  # (P,) over the pool's sets; P = |U| without a pool
    adversarial: jax.Array  # () bool: update p_miss from the scores (modes adversarial and worst)
    masking: jax.Array  # () bool: False in mode "none" (nothing hidden in training)
    rng: jax.Array  # raw uint32 key
    env_steps: jax.Array  # () int32, over all envs
    grad_steps: jax.Array  # () int32
    pool: jax.Array  # (P,) int32 indices into U of the sets scored and drawn by p_miss; (0,) = all of U
    lower_bound: jax.Array  # () float32: l of the adversary's update (pairs of one program may differ)
    # (num_envs,) int32: the env step of each env's episode at which its u fails, drawn from
    # the spec's fail_steps at the episode's start; None where u is hidden from the start (the paper)
    failure_step: jax.Array | None = None
    # () bool: with adversarial, p_miss all on the worst-scored set (mode "worst"). Last and
    # False in the other modes, so their states' fingerprints are those of earlier versions.
    greedy: jax.Array = False


class Trainer:
    """Static parts of a run (env, agent, candidate sets, sizes) and its pure functions."""

    def __init__(self, env, spec: RunSpec):
        self.env = env
        self.spec = spec
        self.sets = SetNumbering(env.observation_size, spec.k, spec.include_empty_set, spec.up_to_k)
        self.num_sets = self.sets.count
        self.pooled = spec.pool_size > 0
        self.num_scored = spec.pool_size or self.num_sets  # P
        self.agent = SAC(2 * env.observation_size, env.action_low, env.action_high, spec.sac)
        self.failing = spec.fail_steps != (0,)  # else the program is the paper's, unchanged

    # --- construction -------------------------------------------------------------------
    def init(self, seed: jax.Array, mode_adversarial: jax.Array, mode_masking: jax.Array,
             lower_bound: jax.Array, mode_greedy: jax.Array = False) -> TrainState:
        """A fresh run. Every argument may be traced: vmap over seeds, modes and lower bounds
        works (:func:`~admissable_jax.host_loop.init_arguments` gives them for a config)."""
        rng = jax.random.PRNGKey(seed)
        rng, agent_rng, env_rng, set_rng = jax.random.split(rng, 4)
        p_miss = uniform_p_miss(self.num_scored)
        if self.pooled:  # until the first search: P random sets (drawn as before where U can be listed)
            set_rng, pool_rng = jax.random.split(set_rng)
            pool = jax.random.choice(pool_rng, self.num_sets, (self.num_scored,), replace=False).astype(jnp.int32) \
                if self.sets.listed else sample_distinct_sets(pool_rng, self.num_sets, self.num_scored)
        else:
            pool = jnp.zeros((0,), jnp.int32)
        adversarial = jnp.asarray(mode_adversarial, bool)
        return TrainState(
            sac=self.agent.init(agent_rng),
            buffer=replay.init_buffer(self.spec.buffer_capacity, self.env.observation_size, self.env.action_size,
                                      self.failing),
            env_states=jax.vmap(self.env.reset)(jax.random.split(env_rng, self.spec.num_envs)),
            set_index=self._draw_sets(set_rng, p_miss, pool, adversarial),
            p_miss=p_miss,
            adversarial=adversarial,
            masking=jnp.asarray(mode_masking, bool),
            rng=rng,
            env_steps=jnp.zeros((), jnp.int32),
            grad_steps=jnp.zeros((), jnp.int32),
            pool=pool,
            lower_bound=jnp.asarray(lower_bound, jnp.float32),
            failure_step=self._draw_failure_steps(set_rng),
            greedy=jnp.asarray(mode_greedy, bool),
        )

    # --- pieces -------------------------------------------------------------------------
    @property
    def hidden_sets(self) -> np.ndarray:
        """U listed: the (|U|, d) 0/1 rows in U's order, built once (``SetNumbering.matrix``);
        ValueError beyond MAX_CANDIDATE_SETS sets (a pool's U is numbered, never listed)."""
        return self.sets.matrix

    def hidden_rows(self, state: TrainState, set_index: jax.Array) -> jax.Array:
        """The 0/1 rows hidden for these set indices (all zeros when not masking)."""
        return self.sets.rows(set_index) * state.masking.astype(jnp.float32)

    def scored_sets(self, pool: jax.Array) -> jax.Array:
        """The 0/1 rows of the sets a scoring round scores: the pool's, or all of U (listed:
        without a pool, U has at most MAX_CANDIDATE_SETS sets)."""
        return self.sets.rows(pool) if self.pooled else self.hidden_sets

    def _draw_sets(self, rng: jax.Array, p_miss: jax.Array, pool: jax.Array, adversarial: jax.Array) -> jax.Array:
        """Each env's set for a new episode, u ~ p_miss, as indices into U (paper §3). With a
        pool, p_miss is over the pool's sets, and with probability ``pool_explore`` (1 in
        uniform mode: uniform over all U) an episode takes a uniformly random set of U."""
        shape = (self.spec.num_envs,)
        if not self.pooled:
            return sample_set_indices(rng, p_miss, shape)
        pick_rng, explore_rng, anywhere_rng = jax.random.split(rng, 3)
        from_pool = pool[sample_set_indices(pick_rng, p_miss, shape)]
        anywhere = jax.random.randint(anywhere_rng, shape, 0, self.num_sets, jnp.int32)
        explore = jax.random.uniform(explore_rng, shape) < jnp.where(adversarial, self.spec.pool_explore, 1.0)
        return jnp.where(explore, anywhere, from_pool)

    def _draw_failure_steps(self, set_rng: jax.Array) -> jax.Array | None:
        """Each env's failure step for a new episode, uniform over the spec's ``fail_steps``
        (None where u is hidden from the start). Its key is folded from the sets' key, so a
        run's draws of u are those of the same seed without failures."""
        if not self.failing:
            return None
        choice = jax.random.randint(jax.random.fold_in(set_rng, 1), (self.spec.num_envs,), 0, len(self.spec.fail_steps))
        return jnp.asarray(self.spec.fail_steps, jnp.int32)[choice]

    def hidden_now(self, state: TrainState) -> jax.Array:
        """The (num_envs, d) 0/1 rows each env's policy has hidden at this step: its episode's
        u, from its failure step on (:func:`~admissable_jax.method.hidden_from_step`)."""
        hidden = self.hidden_rows(state, state.set_index)
        if not self.failing:
            return hidden
        return hidden_from_step(hidden, state.env_states.step_count, state.failure_step)

    def policy(self, actor_params, masked_obs: jax.Array) -> jax.Array:
        """Deterministic policy on one masked observation, as scoring runs it."""
        return self.agent.deterministic_action(actor_params, masked_obs)

    def _act(self, state: TrainState, rng: jax.Array) -> jax.Array:
        random_rng, policy_rng = jax.random.split(rng)
        masked = mask_observation(state.env_states.obs, self.hidden_now(state))
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
        with jax.named_scope("minibatches"):
            batches = jax.vmap(lambda key: self._minibatch(state, key))(sample_keys)

        def one_update(sac_state, batch_and_key):
            with jax.named_scope("updates"):
                return self.agent.update(sac_state, *batch_and_key)

        def updates(sac_state, batches, update_keys):
            sac_state, metrics = jax.lax.scan(one_update, sac_state, (batches, update_keys))
            return sac_state, jax.tree.map(jnp.mean, metrics)

        def skip(sac_state, batches, update_keys):
            _, metrics = jax.eval_shape(updates, sac_state, batches, update_keys)
            return sac_state, jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype), metrics)

        # As SB3: learn once more than learning_starts steps are collected. lazy_cond: vmapped
        # pairs (an experiment) skip the updates too until one of them learns.
        return lazy_cond(self._learning(state), updates, skip, state.sac, batches, update_keys)

    def _minibatch(self, state: TrainState, rng: jax.Array) -> SACBatch:
        """A uniform replay minibatch, masked with each transition's own missing set."""
        return self.masked_batch(state, replay.sample(state.buffer, rng, self.spec.sac.batch_size))

    def masked_batch(self, state: TrainState, transitions: replay.Transitions) -> SACBatch:
        """Stored transitions as SAC learns from them: each observation masked by its
        episode's u, hidden in obs and next_obs alike, or where u fails mid-episode, in each
        from the failure step on (the transition across it: obs whole, next_obs without u)."""
        hidden = self.hidden_rows(state, transitions.set_index)
        obs_hidden = next_hidden = hidden
        if self.failing:
            obs_hidden = hidden_from_step(hidden, transitions.steps_past_failure, 0)
            next_hidden = hidden_from_step(hidden, transitions.steps_past_failure + 1, 0)
        return SACBatch(
            obs=mask_observation(transitions.obs, obs_hidden),
            action=transitions.action,
            reward=transitions.reward,
            next_obs=mask_observation(transitions.next_obs, next_hidden),
            terminated=transitions.terminated,
        )

    def _learning(self, state: TrainState) -> jax.Array:
        return state.env_steps > self.spec.learning_starts

    # --- the iteration ------------------------------------------------------------------
    def iteration(self, state: TrainState, _=None) -> tuple[TrainState, dict[str, jax.Array]]:
        """One step of every env under its episode's u (paper §3: u is drawn from p_miss at
        each episode start and held for the episode; with ``fail_at``, hidden from the
        episode's failure step on), the transitions stored with u's index,
        then ``updates_per_iteration`` SAC updates once learning has started. Pure: a
        ``lax.scan`` body (the second argument is the scanned-over slot, unused). Its parts
        carry JAX named scopes, by which a profile sums the device's time
        (``benchmarks/campaign.py profile``); they change no computation."""
        rng, act_rng, reset_rng, set_rng, learn_rng = jax.random.split(state.rng, 5)
        with jax.named_scope("act"):
            actions = self._act(state, act_rng)
        with jax.named_scope("env_step"):
            stepped = jax.vmap(self.env.step)(state.env_states, actions)
        with jax.named_scope("replay_insert"):
            buffer = replay.insert(
                state.buffer,
                replay.Transitions(
                    obs=state.env_states.obs,
                    set_index=state.set_index,
                    action=actions,
                    reward=stepped.reward,
                    next_obs=stepped.obs,
                    terminated=stepped.terminated,
                    steps_past_failure=state.env_states.step_count - state.failure_step if self.failing else None,
                ),
            )
        done = stepped.done
        with jax.named_scope("episode_starts"):  # resets where an episode ended, and their sets u
            env_states = jax.vmap(reset_where_done, (None, 0, 0))(
                self.env, stepped, jax.random.split(reset_rng, self.spec.num_envs)
            )
            new_sets = self._draw_sets(set_rng, state.p_miss, state.pool, state.adversarial)
            new_failure_steps = self._draw_failure_steps(set_rng)
        state = state.replace(
            buffer=buffer,
            env_states=env_states,
            set_index=jnp.where(done, new_sets, state.set_index),
            failure_step=jnp.where(done, new_failure_steps, state.failure_step) if self.failing else None,
            env_steps=state.env_steps + self.spec.num_envs,
            rng=rng,
        )
        with jax.named_scope("learn"):
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
        batched rollout, or the critic's estimate) and update p_miss (adversarial mode only).
        With a pool: search the pool afresh first, then score its sets (module docstring)."""
        score_rng = jax.random.split(state.rng)[1]  # [0] moves the state's key on: after_scoring
        pool = state.pool
        if self.pooled:
            score_rng, search_rng = jax.random.split(score_rng)
            pool = self._search_pool(state, search_rng)
        scores = self._score(state, score_rng, self.scored_sets(pool), self.spec.score_estimator)
        p_miss = update_p_miss(
            state.p_miss, scores.scores, state.adversarial, state.greedy, state.lower_bound, self.spec.epsilon
        )
        return self.after_scoring(state, p_miss, pool), scores

    def after_scoring(self, state: TrainState, p_miss: jax.Array, pool: jax.Array) -> TrainState:
        """The state a scoring round leaves: its p_miss and pool (as the round set them, or
        as a record of the round says, when a run is fast-forwarded through it) and the
        PRNG key moved on past the round's own key."""
        chex.assert_equal_shape([p_miss, state.p_miss])
        chex.assert_equal_shape([pool, state.pool])
        return state.replace(p_miss=p_miss, pool=pool, rng=jax.random.split(state.rng)[0])

    def fingerprint(self, state: TrainState) -> jax.Array:
        """() uint32 of the state's exact bits (:func:`~admissable_jax.fingerprints.tree_fingerprint`),
        recorded after every scoring so that a fast-forward can check it computes the same run.
        Of the replay buffer's rows it takes those the last interval wrote: every row is
        checked after the interval that wrote it, and hashing the whole buffer (GBs on a GPU)
        would cost XLA:CPU a copy of it (measured: 0.4 GiB for an Ant run's 1M rows)."""
        written = replay.latest(state.buffer, self.spec.iterations_per_scoring * self.spec.num_envs)
        return tree_fingerprint((state.replace(buffer=state.buffer.replace(data=None)), written))

    def _score(self, state: TrainState, rng: jax.Array, hidden_sets: jax.Array, estimator: str) -> MissingnessScores:
        """``hidden_sets``' scores by ``estimator`` with the state's actor and critic; a
        rollout's sensors fail at the spec's ``score_fail_steps``."""
        return score_missingness(
            self.env, self.policy, state.sac.actor_params, rng, hidden_sets, self.spec.score_episodes,
            num_slots=self.spec.score_envs, score_estimator=estimator, critic_fn=self.critic_values,
            critic_params=state.sac.critic_params, score_horizon=self.spec.score_horizon, gamma=self.spec.sac.gamma,
            fail_at=self.spec.score_fail_steps if estimator == "rollout" else 0,
        )

    def _search_pool(self, state: TrainState, rng: jax.Array) -> jax.Array:
        """The P sets of U that a beam search of width P, ranked by ``pool_ranker``, finds
        worst, as indices into U."""
        found = beam_search_worst_sets(
            lambda rows: self._score(state, rng, rows, self.spec.pool_ranker).scores,
            self.env.observation_size, self.spec.k, self.num_scored, self.spec.up_to_k,
        )
        return self.sets.indices(found.rows)
