"""The paper's mechanism inside training, against hand-computed expectations (point mass).

The acting policy is replaced by one whose action *encodes what it saw*: action 0 is the
indicator half of its input dotted with (0.1, 0.2, 0.3, 0.4) (so it names the hidden
feature), action 1 is the x position as it saw it (0 when x is hidden). The replay buffer
then shows, row by row, what the policy was given. The point mass's escape radius is 1.5
here, so episodes end by termination as well as by truncation (15 steps), and a fresh
start (|p| <= sqrt 2) is never beyond it.
"""

from __future__ import annotations

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import TrainConfig, candidate_sets, make_env, score_missingness
from admissable_jax.envs import point_mass
from admissable_jax.run_spec import RunSpec
from admissable_jax.training import Trainer

RADIUS = 1.5
ENVS, LENGTH, LEARNING_STARTS, ITERATIONS = 8, 15, 40, 60
WEIGHTS = np.array([0.1, 0.2, 0.3, 0.4], np.float32)


def _seen(masked: jax.Array) -> jax.Array:
    """An action that says what the policy saw: (indicator · WEIGHTS, 5 × visible x). The
    buffer keeps it as given; the env clips it to (-1, 1), pushing y away from home."""
    return jnp.stack([masked[..., 4:] @ WEIGHTS, 5.0 * masked[..., 0]], axis=-1)


def _trainer(**changes) -> Trainer:
    settings = dict(env="point_mass", num_envs=ENVS, score_every=ENVS, episode_length=LENGTH,
                    learning_starts=LEARNING_STARTS, batch_size=8, hidden_size=16, buffer_size=ENVS * ITERATIONS,
                    score_episodes=2, progress=False)
    config = TrainConfig(**{**settings, **changes}).resolved()
    spec = RunSpec.of(config)
    return Trainer(make_env("point_mass", spec.env_options), spec)


@pytest.fixture(scope="module", autouse=True)
def escape_radius():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(point_mass, "_ESCAPE_RADIUS", RADIUS)
        yield


@pytest.fixture(scope="module")
def k1(escape_radius):
    """One compiled 60-iteration scan, run from three starts: adversarial with a spread
    p_miss; every env on u = {0} with p_miss all on {3}; mode none."""
    trainer = _trainer()
    trainer.agent.sample_action = lambda params, masked, rng: (_seen(masked), jnp.zeros(masked.shape[:-1]))

    def run(state):
        def iteration(state, _):
            before = state.set_index
            state, _ = trainer.iteration(state)
            return state, (before, state.set_index, state.env_states.step_count)

        return jax.lax.scan(iteration, state, None, length=ITERATIONS)

    run = jax.jit(run)
    start = trainer.init(0, True, True, 0.0)
    spread = start.replace(p_miss=jnp.asarray(WEIGHTS))
    on_three = start.replace(p_miss=jnp.array([0.0, 0.0, 0.0, 1.0]), set_index=jnp.zeros(ENVS, jnp.int32))
    return trainer, {name: run(state) for name, state in
                     (("spread", spread), ("on_three", on_three), ("none", start.replace(masking=jnp.array(False))))}


def _rows(state):
    """Buffer rows as (iteration, env) arrays (no wrap: capacity = ENVS × ITERATIONS)."""
    return jax.tree.map(lambda x: np.asarray(x).reshape(ITERATIONS, ENVS, *x.shape[1:]), state.buffer.data)


def test_acting_policy_sees_its_envs_u_and_warm_up_is_uniform(k1):
    trainer, runs = k1
    state, (set_before, _, _) = runs["spread"]
    rows = _rows(state)
    np.testing.assert_array_equal(rows.set_index, np.asarray(set_before))  # the buffer keeps each step's u
    warm = np.arange(ITERATIONS) * ENVS < LEARNING_STARTS  # env steps before the iteration
    assert warm.sum() == 5
    policy = rows.action[~warm]
    np.testing.assert_allclose(policy[..., 0], WEIGHTS[rows.set_index[~warm]], rtol=1e-6)
    np.testing.assert_allclose(policy[..., 1], np.where(rows.set_index[~warm] == 0, 0.0, 5 * rows.obs[~warm][..., 0]),
                               rtol=1e-6)
    assert len(np.unique(rows.set_index[~warm])) == 4
    # Warm-up: uniform in the action bounds (-1, 1), nothing like the policy's encoding.
    random = rows.action[warm].reshape(-1)
    assert np.all((random >= -1) & (random <= 1)) and 0.45 < random.std() < 0.7 and abs(random.mean()) < 0.25
    assert not np.isclose(rows.action[warm][..., 0], WEIGHTS[rows.set_index[warm]]).any()
    # Mode none: the policy sees everything and an all-zero indicator.
    rows_none = _rows(runs["none"][0])
    np.testing.assert_array_equal(rows_none.action[~warm][..., 0], 0.0)
    np.testing.assert_allclose(rows_none.action[~warm][..., 1], 5 * rows_none.obs[~warm][..., 0], rtol=1e-6)


def test_buffer_keeps_termination_and_the_terminal_observation(k1):
    _, runs = k1
    state, (_, _, step_count) = runs["spread"]
    rows = _rows(state)
    reset = np.asarray(step_count) == 0  # the env started a new episode after this step
    terminal = np.linalg.norm(rows.next_obs[..., :2], axis=-1) > RADIUS
    np.testing.assert_array_equal(rows.terminated, terminal)  # termination, by the env's own rule
    assert terminal.any() and (reset & ~terminal).any()  # both terminations and truncations happened
    assert not rows.terminated[reset & ~terminal].any()  # a truncation is stored as not terminated
    np.testing.assert_array_equal(reset, terminal | (_episode_step(reset) == LENGTH))  # truncated at 15 steps
    # next_obs is the observation before the automatic reset: beyond the radius, where no
    # fresh start can be; the env's next observation is the fresh start.
    following = rows.obs[1:][reset[:-1]]
    assert np.all(np.linalg.norm(following[..., :2], axis=-1) <= np.sqrt(2) + 1e-6)
    assert not np.isclose(following, rows.next_obs[:-1][reset[:-1]]).all(axis=-1).any()


def _episode_step(reset: np.ndarray) -> np.ndarray:
    """The step number within its episode of every (iteration, env) step, from the resets."""
    steps = np.zeros(reset.shape, int)
    count = np.zeros(reset.shape[1], int)
    for t in range(reset.shape[0]):
        count += 1
        steps[t] = count
        count[reset[t]] = 0
    return steps


def test_u_is_fixed_within_an_episode_and_redrawn_at_every_reset(k1):
    _, runs = k1
    for name in ("spread", "on_three"):
        set_before, set_after, step_count = (np.asarray(x) for x in runs[name][1])
        reset = step_count == 0
        # Within an episode u never changes.
        assert (set_after[~reset] == set_before[~reset]).all()
    # All of p_miss on {3}, every env starting on {0}: {0} until the env's first reset, {3}
    # after every reset, whether it ended in a termination or a truncation.
    state, (set_before, set_after, step_count) = runs["on_three"]
    set_before, set_after, reset = np.asarray(set_before), np.asarray(set_after), np.asarray(step_count) == 0
    rows = _rows(state)
    assert (set_after[reset] == 3).all()
    first_reset = reset.argmax(axis=0)
    for env in range(ENVS):
        assert (set_before[: first_reset[env] + 1, env] == 0).all()
    assert (rows.terminated & reset).any() and (reset & ~rows.terminated).any()


def test_each_minibatch_row_is_masked_with_its_own_u(k1):
    trainer, runs = k1
    for name, masking in (("spread", True), ("none", False)):
        state = runs[name][0]
        rows = jax.tree.map(np.asarray, state.buffer.data)
        batches = jax.jit(jax.vmap(lambda key: trainer._minibatch(state, key)))(jax.random.split(jax.random.key(3), 16))
        obs, next_obs = (np.asarray(x).reshape(-1, 8) for x in (batches.obs, batches.next_obs))
        for sampled, sampled_next in zip(obs, next_obs):
            hidden = sampled[4:]
            row = np.flatnonzero(np.isclose(rows.obs, sampled[:4] + hidden * rows.obs).all(axis=1))
            assert len(row) == 1
            expected_hidden = np.eye(4)[rows.set_index[row[0]]] * masking  # the row's own u
            np.testing.assert_array_equal(hidden, expected_hidden)
            np.testing.assert_allclose(sampled[:4], rows.obs[row[0]] * (1 - expected_hidden))
            np.testing.assert_allclose(sampled_next, np.concatenate([rows.next_obs[row[0]] * (1 - expected_hidden),
                                                                     expected_hidden]))


def _controller(params, masked):
    """Homes both coordinates it can see; pushes y outward when x is hidden."""
    x_hidden = masked[4] > 0
    home = jnp.clip(-2.0 * masked[:2], -1.0, 1.0)
    return jnp.where(x_hidden, jnp.array([0.0, 1.0]) * jnp.sign(masked[1] + 1e-6), home)


def test_the_next_chunk_draws_from_the_p_miss_the_scoring_just_set(escape_radius):
    """Scores of the controller: hiding x is far worst. With l between that score and the
    next, p_miss after the scoring puts all but ~1e-8 of its mass on {0}; every episode the
    following chunk starts must then hide x."""
    trainer = _trainer(num_envs=20, score_every=20, episode_length=5, learning_starts=10_000, epsilon=1e-8)
    state = trainer.init(1, True, True, 0.0)
    # The scores the trainer's scoring will see: its own rng split, env and slots.
    first = jax.jit(score_missingness, static_argnums=(0, 1, 5, 6, 7))(
        trainer.env, _controller, None, jax.random.split(state.rng)[1], trainer.hidden_sets,
        trainer.spec.score_episodes, None, trainer.spec.score_envs)
    scores = np.sort(np.asarray(first.scores))
    assert int(first.argmin) == 0 and scores[0] < scores[1] - 0.05
    lower_bound = float(scores[:2].mean())
    state = state.replace(lower_bound=jnp.float32(lower_bound))  # l is the run's data
    trainer.policy = _controller

    def score_then_train(state):
        state, scores = trainer.score_and_update(state)
        return trainer.run_chunk(state, 24)[0], scores  # 24 × 20 env steps fill the buffer exactly

    state, scored = jax.jit(score_then_train)(state)
    # The hand-computed update: {0} clipped to l gets 1/ε, the others 1/(a_u - l).
    weights = np.array([1 / 1e-8] + [1 / (a - lower_bound + 1e-8) for a in np.asarray(scored.scores)[1:]])
    np.testing.assert_allclose(np.asarray(scored.scores), np.asarray(first.scores), rtol=1e-6)
    np.testing.assert_allclose(state.p_miss, weights / weights.sum(), rtol=1e-4)
    rows = np.asarray(state.buffer.data.set_index).reshape(24, 20)
    assert (rows[5:] == 0).all()  # every env has restarted by iteration 5 (5-step episodes)
    assert (np.asarray(state.set_index) == 0).all()


def test_scoring_with_sensors_failing_scores_what_score_missingness_does_with_those_steps(escape_radius):
    """``score_fail_at``: the trainer's scoring round (and so p_miss) is score_missingness's with
    each set's N = 2 episodes failing at env steps 0 and 3, not the paper's from-the-start
    round; the pool's critic ranker would still value starts, so only rollouts take the steps."""
    trainer = _trainer(score_fail_at="3,0")
    assert trainer.spec.score_fail_steps == (0, 3)
    trainer.policy = _controller
    initial = trainer.init(1, True, True, 0.0)
    state, scored = jax.jit(trainer.score_and_update)(initial)
    direct = jax.jit(score_missingness, static_argnums=(0, 1, 5, 6, 7), static_argnames="fail_at")
    arguments = (trainer.env, _controller, None, jax.random.split(initial.rng)[1],
                 trainer.hidden_sets, trainer.spec.score_episodes, None, trainer.spec.score_envs)
    np.testing.assert_allclose(np.asarray(scored.returns), np.asarray(direct(*arguments, fail_at=(0, 3)).returns), rtol=1e-6)
    assert not np.allclose(np.asarray(scored.scores), np.asarray(direct(*arguments).scores))  # (the paper's round)
    weights = 1 / (np.asarray(scored.scores) + 1e-8)
    np.testing.assert_allclose(state.p_miss, weights / weights.sum(), rtol=1e-4)


def test_up_to_two_missing_features_and_the_empty_set_in_training_and_scoring(escape_radius):
    """U = {u : |u| <= 2} with ``up_to_k``: the empty set, 4 single features, 6 pairs."""
    trainer = _trainer(k=2, include_empty_set=True, up_to_k=True)
    np.testing.assert_array_equal(trainer.hidden_sets, candidate_sets(4, 2, include_empty=True, up_to_k=True))
    assert trainer.num_sets == 11 and np.asarray(trainer.hidden_sets).sum(axis=1).tolist() == [0] + [1] * 4 + [2] * 6
    trainer.agent.sample_action = lambda params, masked, rng: (_seen(masked), jnp.zeros(masked.shape[:-1]))
    trainer.policy = _controller
    state = trainer.init(0, True, True, 0.0).replace(p_miss=jnp.full(11, 1 / 11))

    def run(state):
        state, _ = trainer.run_chunk(state, ITERATIONS)
        return trainer.score_and_update(state)

    state, scored = jax.jit(run)(state)
    rows = _rows(state)
    sets = np.asarray(trainer.hidden_sets)[rows.set_index]
    policy = np.arange(ITERATIONS) * ENVS >= LEARNING_STARTS
    np.testing.assert_allclose(rows.action[policy][..., 0], sets[policy] @ WEIGHTS, rtol=1e-6)
    np.testing.assert_allclose(rows.action[policy][..., 1], np.where(sets[policy][..., 0] > 0, 0.0, 5 * rows.obs[policy][..., 0]),
                               rtol=1e-6)
    drawn = np.unique(rows.set_index)
    assert 0 in drawn and {1, 2} & set(drawn) and {5, 6} & set(drawn)  # ~50 draws of 11: empty, single, pair
    # Scoring: 11 sets, each from the same start states; the empty set is the clean case.
    assert scored.scores.shape == (11,) and scored.returns.shape == (12, 2)
    np.testing.assert_allclose(scored.scores[0], scored.clean_score, rtol=1e-6)
    assert float(scored.scores[1]) < float(scored.clean_score)  # {0}: the controller loses x


@pytest.mark.parametrize("up_to_k", [False, True])
def test_a_pool_over_sets_of_up_to_k_features_keeps_a_single_feature_that_beats_every_pair(up_to_k):
    """The pool search's finalists as indices into U. Scored by rows · (-1, 2.5, 3, 4), {0}
    (-1) is worse than every pair: with ``up_to_k`` the pool of 3 is {0}, {0,1}, {0,2};
    with exactly k it is the three worst pairs the beam reached."""
    trainer = _trainer(k=2, up_to_k=up_to_k, pool_size=3)
    assert trainer.num_sets == (10 if up_to_k else 6) and trainer.num_scored == 3
    weights = jnp.array([-1.0, 2.5, 3.0, 4.0])
    trainer._score = lambda state, rng, rows, estimator: types.SimpleNamespace(scores=rows @ weights)
    pool = np.asarray(trainer._search_pool(None, jax.random.key(0)))
    found = [tuple(np.flatnonzero(row)) for row in np.asarray(trainer.hidden_sets)[pool]]
    assert found == ([(0,), (0, 1), (0, 2)] if up_to_k else [(0, 1), (0, 2), (0, 3)])
