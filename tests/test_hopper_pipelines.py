"""Hopper end to end on both physics backends: ``train_fn`` on MJX's JAX implementation, an
experiment of two (seed, mode) pairs on MuJoCo Warp (on the CPU here), and the two checked
against each other.

Warp programs compile in seconds, so the Warp side runs the whole experiment pipeline
(nested vmap over Warp data, checkpoints, resume); the JAX side is one short ``train_fn``
run (each JAX Hopper program costs a minute or more to compile on a small CPU). Short
horizons, where float32 physics on the two backends agree.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import TrainConfig, make_env
from admissable_jax.experiment import ExperimentConfig, run_experiment
from admissable_jax.host_loop import PhysicsCapacityExceeded
from admissable_jax.train import train_fn

# 80 env steps in 2 scorings of 40 (10 iterations of 4 envs each); learning from step 48.
HOPPER = dict(
    env="hopper", score_every=40, num_envs=4, learning_starts=48, batch_size=32, hidden_size=32,
    buffer_size=1000, score_episodes=2, score_envs=8, episode_length=25, checkpoint_every=1, progress=False,
)


@pytest.fixture(scope="module")
def jax_run(tmp_path_factory):
    """Adversarial seed 0 on the JAX backend, through train_fn."""
    out = str(tmp_path_factory.mktemp("hopper") / "jax")
    return train_fn(TrainConfig(**HOPPER, physics="jax", total_steps=80, missingness="adversarial", out=out))


@pytest.fixture(scope="module")
def warp_experiment(tmp_path_factory):
    """(adversarial, uniform) × seed 0 on Warp, vmapped in one program."""
    out = str(tmp_path_factory.mktemp("hopper") / "warp")
    return run_experiment(ExperimentConfig(**HOPPER, physics="warp", seeds=1, modes="adversarial,uniform",
                                           total_steps=80, out=out))


def test_short_hopper_run_through_train_fn(jax_run):
    assert jax_run.config.physics == "jax" and jax_run.trainer.env.physics_name == "jax"
    assert [row["env_steps"] for row in jax_run.scores] == [40, 80]
    for row in jax_run.scores:
        assert len(row["scores"]) == 11
        assert 0 < row["mean_episode_length"] <= 25
        assert np.isfinite(row["clean_score"])
        assert row["min_score"] == min(row["scores"])
    # Learning starts once more than 48 env steps are collected: after iteration 13 of 20
    # (4 envs each), so iterations 13..20 take 4 gradient steps each.
    assert [row["grad_steps"] for row in jax_run.metrics] == [0, 8 * 4]
    assert int(jax_run.state.grad_steps) == 32 and int(jax_run.state.env_steps) == 80
    assert sorted(os.listdir(os.path.join(jax_run.run_dir, "checkpoints"))) == ["40", "80"]


def test_warp_experiment_matches_jax_train_fn(jax_run, warp_experiment):
    """The Warp experiment's adversarial pair and the JAX backend's unbatched run of the same
    seed and mode: same buffer, same scores, the same learning."""
    warp = warp_experiment[0]
    assert (warp.config.missingness, warp.config.seed, warp.config.physics) == ("adversarial", 0, "warp")
    assert warp.trainer.env.physics_name == "warp"
    assert int(warp.state.grad_steps) == int(jax_run.state.grad_steps) == 32
    assert [row["episodes"] for row in warp.metrics] == [row["episodes"] for row in jax_run.metrics]
    np.testing.assert_allclose(warp.state.buffer.data.obs, jax_run.state.buffer.data.obs, atol=2e-3)
    np.testing.assert_allclose(warp.state.buffer.data.reward, jax_run.state.buffer.data.reward, atol=2e-3)
    for warp_row, jax_row in zip(warp.scores, jax_run.scores):
        np.testing.assert_allclose(warp_row["scores"], jax_row["scores"], rtol=1e-3, atol=1e-2)
        np.testing.assert_allclose(warp_row["clean_score"], jax_row["clean_score"], rtol=1e-3, atol=1e-2)
        np.testing.assert_allclose(warp_row["p_miss"], jax_row["p_miss"], rtol=1e-3)
    # 32 Adam steps move each parameter by at most ~1e-2, so compare what learning changed
    # (relative), not the parameters (which are mostly their common initialisation).
    initial = jax_run.trainer.agent.init(jax.random.split(jax.random.PRNGKey(0), 4)[1]).actor_params
    for warp_leaf, jax_leaf, start in zip(*(jax.tree.leaves(p) for p in (warp.actor_params, jax_run.actor_params, initial))):
        jax_change, warp_change = np.asarray(jax_leaf - start), np.asarray(warp_leaf - start)
        assert np.linalg.norm(jax_change) > 0
        assert np.linalg.norm(warp_change - jax_change) <= 0.05 * np.linalg.norm(jax_change)


def test_warp_experiment_pairs_and_resume_repeat_the_straight_run(warp_experiment, tmp_path):
    """Nested vmap over Warp data: the uniform pair kept p_miss; a run paused after its first
    scoring (time limit) and resumed from the checkpoint holding Warp data repeats the
    uninterrupted run exactly."""
    straight = warp_experiment
    assert [r.config.physics for r in straight] == ["warp", "warp"]
    np.testing.assert_allclose(straight[1].scores[-1]["p_miss"], 1 / 11, rtol=1e-6)
    assert not np.allclose(straight[0].scores[-1]["p_miss"], 1 / 11)
    shared = dict(**HOPPER, physics="warp", seeds=1, modes="adversarial,uniform", total_steps=80,
                  out=str(tmp_path / "resumed"))
    paused = run_experiment(ExperimentConfig(**shared, time_limit=1e-3))
    assert [row["env_steps"] for row in paused[0].scores] == [40] and not paused[0].finished
    resumed = run_experiment(ExperimentConfig(**shared, resume=True))
    for a, b in zip(straight, resumed):
        assert b.finished
        assert [row["scores"] for row in a.scores] == [row["scores"] for row in b.scores]
        assert [row["p_miss"] for row in a.scores] == [row["p_miss"] for row in b.scores]


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
