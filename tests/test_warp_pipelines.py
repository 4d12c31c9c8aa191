"""Every pipeline on MuJoCo Warp (on the CPU here), checked against the JAX backend.

Warp programs compile in seconds, so these run Hopper end to end: a training chunk and a
scoring round from the same start on both backends (short horizons, where float32 physics
agree), an experiment of two (seed, mode) pairs vmapped over Warp data with a checkpoint
resume, and the error a run gives when Warp's contact buffer is too small.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import TrainConfig, make_env
from admissable_jax.experiment import ExperimentConfig, run_experiment
from admissable_jax.host_loop import PhysicsCapacityExceeded, make_trainer
from admissable_jax.train import train_fn

HOPPER = TrainConfig(
    env="hopper", total_steps=80, score_every=40, num_envs=4, learning_starts=48, batch_size=32,
    hidden_size=32, buffer_size=1000, score_episodes=2, score_envs=8, episode_length=25, progress=False,
)


def _chunk_and_score(physics: str):
    trainer = make_trainer(dataclasses.replace(HOPPER, physics=physics).resolved())
    assert trainer.env.physics_name == physics

    def run(state):
        state, metrics = trainer.run_chunk(state, 16)  # 64 env steps, learning from step 48
        state, scores = trainer.score_and_update(state)
        return state, metrics, scores

    return jax.jit(run)(trainer.init(0, True, True))


def test_training_chunk_and_scoring_on_warp_match_jax():
    (jax_state, jax_metrics, jax_scores) = _chunk_and_score("jax")
    (warp_state, warp_metrics, warp_scores) = _chunk_and_score("warp")
    assert int(warp_state.grad_steps) == int(jax_state.grad_steps) > 0
    assert not np.asarray(warp_metrics["capacity_exceeded"]).any()
    assert not bool(warp_scores.capacity_exceeded)
    # The same transitions reached the replay buffer, and the same episodes ended.
    np.testing.assert_allclose(warp_state.buffer.data.obs, jax_state.buffer.data.obs, atol=2e-3)
    np.testing.assert_allclose(warp_state.buffer.data.reward, jax_state.buffer.data.reward, atol=2e-3)
    np.testing.assert_array_equal(warp_metrics["episodes"], jax_metrics["episodes"])
    # The learned networks, and the scoring round run with them, agree.
    for warp_leaf, jax_leaf in zip(jax.tree.leaves(warp_state.sac.actor_params), jax.tree.leaves(jax_state.sac.actor_params)):
        np.testing.assert_allclose(warp_leaf, jax_leaf, atol=1e-3)
    np.testing.assert_array_equal(warp_scores.lengths, jax_scores.lengths)
    np.testing.assert_allclose(warp_scores.returns, jax_scores.returns, rtol=1e-3, atol=1e-2)
    np.testing.assert_allclose(warp_state.p_miss, jax_state.p_miss, rtol=1e-3)


def test_experiment_on_warp_vmaps_pairs_and_resumes_exactly(tmp_path):
    """Two (seed, mode) pairs × 4 envs in one program: nested vmap over Warp data; the
    checkpoint holds Warp data and a resumed run repeats the uninterrupted one exactly."""
    shared = dict(
        env="hopper", seeds=1, modes="adversarial,uniform", physics="warp", score_every=40, num_envs=4,
        learning_starts=48, batch_size=32, hidden_size=32, buffer_size=1000, score_episodes=2,
        score_envs=8, episode_length=25, checkpoint_every=1, progress=False,
    )
    straight = run_experiment(ExperimentConfig(**shared, total_steps=80, out=str(tmp_path / "straight")))
    assert [r.config.physics for r in straight] == ["warp", "warp"]
    run_experiment(ExperimentConfig(**shared, total_steps=40, out=str(tmp_path / "resumed")))
    resumed = run_experiment(ExperimentConfig(**shared, total_steps=80, out=str(tmp_path / "resumed"), resume=True))
    for a, b in zip(straight, resumed):
        assert [row["env_steps"] for row in a.scores] == [40, 80]
        assert [row["scores"] for row in a.scores] == [row["scores"] for row in b.scores]
    # Each pair of the batch is the unbatched program's run: the uniform pair kept p_miss.
    np.testing.assert_allclose(straight[1].scores[-1]["p_miss"], 1 / 11, rtol=1e-6)


def test_capacity_overflow_is_detected_and_stops_the_run_in_one_line(tmp_path, monkeypatch):
    """A batch larger than the env's max_batch overflows Warp's shared contact buffer and the
    env says so; a run whose env says so stops with an error naming the setting."""
    def overflowed(max_batch: int) -> bool:
        env = make_env("hopper", physics="warp", max_batch=max_batch)
        actions = np.zeros((8, env.action_size), np.float32)

        def fall(states, _):  # 8 Hoppers fall onto the floor: contacts in every world
            states = jax.vmap(env.step)(states, actions)
            return states, env.capacity_exceeded(states)

        states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 8))
        return bool(jax.jit(lambda s: jax.lax.scan(fall, s, None, length=40)[1].any())(states))

    assert overflowed(max_batch=1) and not overflowed(max_batch=8)

    # The loop's side, on the point mass (seconds): an env that reports an overflow
    # mid-run stops it with one line naming the setting and the kept checkpoint.
    from admissable_jax.envs import PointMass

    monkeypatch.setattr(PointMass, "capacity_exceeded", lambda self, state: jnp.any(state.step_count >= 40))
    monkeypatch.setattr(PointMass, "capacity_message", lambda self: "contacts (naconmax) sized for max_batch=1 worlds; raise max_batch")
    config = TrainConfig(env="point_mass", total_steps=3000, score_every=500, num_envs=4, learning_starts=1000,
                         episode_length=100, score_episodes=2, batch_size=32, buffer_size=5000, checkpoint_every=1,
                         progress=False, out=str(tmp_path / "overflow"))
    with pytest.raises(PhysicsCapacityExceeded, match="at env step 500: .*raise max_batch; no checkpoint yet") as error:
        train_fn(config)
    assert "\n" not in str(error.value)
