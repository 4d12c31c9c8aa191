"""The Gymnasium wrappers and score_policy, against hand-computed values (NumPy only, no JAX)."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from admissable_jax.wrappers import AdversarialMissingness, MissingnessObservation, score_policy


class ConstantFeatures(gymnasium.Env):
    """Observes (1, 2, 3) always; the reward is the action; 5-step episodes. A policy that
    acts with the sum of what it sees earns 5 · (6 − the hidden feature's value)."""

    observation_space = gymnasium.spaces.Box(-10.0, 10.0, (3,), np.float32)
    action_space = gymnasium.spaces.Box(-100.0, 100.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.steps = 0
        return np.array([1.0, 2.0, 3.0], np.float32), {}

    def step(self, action):
        self.steps += 1
        return np.array([1.0, 2.0, 3.0], np.float32), float(action[0]), False, self.steps >= 5, {}


gymnasium.register("ConstantFeatures-v0", entry_point=ConstantFeatures)


def sum_of_visible(masked_obs: np.ndarray) -> np.ndarray:
    return masked_obs[:, :3].sum(axis=1, keepdims=True)


def test_score_policy_gives_the_papers_a_u_for_a_numpy_policy(capsys):
    result = score_policy("ConstantFeatures-v0", sum_of_visible, k=1, n_episodes=3, num_envs=5, progress=True)
    assert "12/12 " in capsys.readouterr().err  # the bar over the episodes, finished
    np.testing.assert_allclose(result.scores, [25.0, 20.0, 15.0])  # hide 1, 2 or 3 of 6
    assert result.clean_score == 30.0
    np.testing.assert_array_equal(result.lengths, 5)
    assert result.returns.shape == (4, 3) and not result.capacity_exceeded
    # 12 episodes on 5 slots: slots 0 and 1 run three back to back, 5 steps each plus the
    # vector env's autoreset step between them: 3 · 6 − 1 = 17 steps.
    assert result.loop_steps == 17
    pairs = score_policy("ConstantFeatures-v0", lambda obs: (sum_of_visible(obs), None), k=2, n_episodes=1, num_envs=2)
    np.testing.assert_allclose(pairs.scores, [15.0, 10.0, 5.0])  # {0,1}, {0,2}, {1,2}; SB3-style tuple taken
    up_to_two = score_policy("ConstantFeatures-v0", sum_of_visible, k=2, up_to_k=True, n_episodes=1, num_envs=2)
    np.testing.assert_allclose(up_to_two.scores, [25.0, 20.0, 15.0, 15.0, 10.0, 5.0])  # singles, then pairs
    # Sensors that fail at env step 2: each episode's first 2 steps see all 6, its last 3 the
    # rest; 8 episodes on 3 slots, so slots run episodes back to back (each from step 0 again).
    failing = score_policy("ConstantFeatures-v0", sum_of_visible, k=1, n_episodes=2, num_envs=3, fail_at=2)
    np.testing.assert_allclose(failing.scores, [27.0, 24.0, 21.0])  # 2 · 6 + 3 · (6 − 1, 2 or 3)
    assert failing.clean_score == 30.0
    # Failing at env step 2 or 4: each set's 4 episodes split, episode i failing at the (i mod 2)-th
    # step: at 2 (as above) or at 4 (4 · 6 + 1 · (6 − v)); the clean row fails nowhere.
    spread = score_policy("ConstantFeatures-v0", sum_of_visible, k=1, n_episodes=4, num_envs=3, fail_at=[4, 2])
    np.testing.assert_allclose(spread.returns, [[27.0, 29.0] * 2, [24.0, 28.0] * 2, [21.0, 27.0] * 2, [30.0] * 4])
    with pytest.raises(ValueError, match=r"^fail_at=0,2,4 splits each set's n_episodes=2 episodes unevenly: give "
                                         r"n_episodes a multiple of 3$"):
        score_policy("ConstantFeatures-v0", sum_of_visible, n_episodes=2, fail_at="0,2,4")
    with pytest.raises(ValueError, match=r"^fail_at must be an env step >= 0 \(0: hidden from the start\), got -1$"):
        score_policy("ConstantFeatures-v0", sum_of_visible, fail_at=-1)
    with pytest.raises(ValueError, match="^fail_at=1000 is not below the episodes' 1000 steps: nothing would fail$"):
        score_policy("Hopper-v5", sum_of_visible, fail_at=1000)  # (its registered time limit)
    adversary = AdversarialMissingness(ConstantFeatures(), k=2, up_to_k=True, seed=0)
    np.testing.assert_array_equal(adversary.candidate_sets, up_to_two.hidden_sets)
    assert adversary.update(up_to_two.scores).shape == (6,)
    for counts in (dict(n_episodes=0), dict(num_envs=0)):  # refused before any env is made
        with pytest.raises(ValueError, match="^n_episodes and num_envs must be >= 1$"):
            score_policy("ConstantFeatures-v0", sum_of_visible, **counts)
    # A policy whose batch is not the vector env's actions: a wider action (Gymnasium would
    # hand each env its row and the env read the first entry, silently), none at all.
    for policy, got in ((lambda obs: np.zeros((len(obs), 5)), r"shape \(2, 5\)"), (lambda obs: None, "None")):
        with pytest.raises(ValueError, match=rf"^policy must return a batch of actions of shape \(2, 1\) \(one per "
                                             rf"env\), got {got}$"):
            score_policy("ConstantFeatures-v0", policy, n_episodes=1, num_envs=2)


def test_masked_observation_and_its_space():
    env = MissingnessObservation(ConstantFeatures(), hidden=[1])
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(obs, [1.0, 0.0, 3.0, 0.0, 1.0, 0.0])
    assert info["hidden"] == [1] and env.observation_space.shape == (6,)
    np.testing.assert_array_equal(env.observation_space.low, [-10, -10, -10, 0, 0, 0])
    check_env(env, skip_render_check=True)
    # Features bounded away from 0 still read 0 when hidden: the space widens to hold it.
    positive = type("PositiveFeatures", (ConstantFeatures,),
                    {"observation_space": gymnasium.spaces.Box(0.5, 4.0, (3,), np.float32)})()
    masked = MissingnessObservation(positive, hidden=[1])
    assert masked.observation_space.contains(masked.reset(seed=0)[0])
    hopper = MissingnessObservation(gymnasium.make("Hopper-v5"), hidden=[0, 5])
    check_env(hopper, skip_render_check=True)
    assert hopper.observation_space.shape == (22,) and hopper.reset(seed=1)[0][[0, 5, 11, 16]].tolist() == [0, 0, 1, 1]
    # One u per episode, from the wrapper's own generator, reproducible by seed.
    per_episode = MissingnessObservation(ConstantFeatures(), hidden=lambda rng: [int(rng.integers(3))])
    drawn = [per_episode.reset(seed=seed)[1]["hidden"] for seed in (5, 6, 5)]
    assert drawn[0] == drawn[2]
    with pytest.raises(ValueError, match=r"hidden features must be in \[0, 3\)"):
        MissingnessObservation(ConstantFeatures(), hidden=[3])
    # Sensors that fail at env step 2: every feature (and a 0 indicator) until then, u after.
    failing = MissingnessObservation(ConstantFeatures(), hidden=[1], fail_at=2)
    seen = [failing.reset(seed=0)[0]] + [failing.step(np.zeros(1))[0] for _ in range(3)]
    np.testing.assert_array_equal(seen, [[1, 2, 3, 0, 0, 0]] * 2 + [[1, 0, 3, 0, 1, 0]] * 2)
    assert failing.reset()[0].tolist() == [1, 2, 3, 0, 0, 0]  # a new episode sees u again until step 2
    check_env(failing, skip_render_check=True)
    # A list draws one step per episode from the wrapper's generator; steps past the limit are refused.
    onsets = MissingnessObservation(gymnasium.make("ConstantFeatures-v0", max_episode_steps=5), hidden=[0], fail_at=[3, 0])
    drawn = {onsets.reset(seed=seed)[1]["fail_at"] for seed in range(20)}
    assert drawn == {0, 3} and onsets.fail_steps == (0, 3)
    with pytest.raises(ValueError, match="^fail_at=5 is not below the episodes' 5 steps: nothing would fail$"):
        MissingnessObservation(gymnasium.make("ConstantFeatures-v0", max_episode_steps=5), hidden=[0], fail_at=[0, 5])
    # One index is one feature; a string's characters, or a fraction, are no indices; nor is a 0/1 row of
    # another length (a bool row, or floats that would read as repeated indices).
    np.testing.assert_array_equal(MissingnessObservation(ConstantFeatures(), hidden=2).hidden_row, [0, 0, 1])
    np.testing.assert_array_equal(MissingnessObservation(ConstantFeatures(), hidden=[True, False, True]).hidden_row,
                                  [1, 0, 1])
    for hidden, error, message in (("12", TypeError, "hidden must be feature indices or a 0/1 row, got the string '12'"),
                                   ([1.5], ValueError, "hidden features must be whole indices, got [1.5]"),
                                   ([True, False], ValueError, "a 0/1 row of hidden features needs d = 3 entries, got "
                                                               "shape (2,)"),
                                   ([0.0, 1.0, 0.0, 1.0], ValueError, "hidden features are given twice in [0, 1, 0, 1]: "
                                                                      "give each index once, or a 0/1 row of d = 3 "
                                                                      "entries")):
        with pytest.raises(error, match=f"^{re.escape(message)}$"):
            MissingnessObservation(ConstantFeatures(), hidden=hidden)
    # A feature of a dict or image observation has no single index to hide: refused, not a traceback.
    pictures = type("Pictures", (ConstantFeatures,), {"observation_space": gymnasium.spaces.Box(0, 255, (2, 2), np.uint8)})
    with pytest.raises(ValueError, match=r"^MissingnessObservation needs a flat Box observation space, got Box\(0, 255, "
                                         r"\(2, 2\), uint8\)$"):
        MissingnessObservation(pictures(), hidden=[0])


def test_adversary_draws_from_the_papers_p_miss_and_updates_in_vector_envs():
    env = AdversarialMissingness(ConstantFeatures(), k=1, mode="adversarial", seed=0)
    check_env(env, skip_render_check=True)
    # p_miss ∝ 1/(a_u − l + ε): scores 25, 20, 15 give weights 1/25, 1/20, 1/15, normalised
    # by their sum 47/300: 12/47, 15/47, 20/47.
    np.testing.assert_allclose(env.update([25.0, 20.0, 15.0]), np.array([12, 15, 20]) / 47, rtol=1e-6)
    draws = []
    for _ in range(3000):
        obs, info = env.reset()
        (hidden,) = info["hidden"]
        assert obs[hidden] == 0.0 and obs[3 + hidden] == 1.0 and env.set_index == hidden
        for _ in range(2):  # u stays for the whole episode
            obs, *_ = env.step(np.zeros(1, np.float32))
            assert obs[3 + hidden] == 1.0 and obs[:3].sum() == 6.0 - (hidden + 1)
        draws.append(hidden)
    frequencies = np.bincount(draws, minlength=3) / len(draws)
    np.testing.assert_allclose(frequencies, np.array([12, 15, 20]) / 47, atol=4 * np.sqrt(0.25 / len(draws)))
    # A score below l counts as l: with l = 20, 15 and 20 both weigh 1/ε.
    clipped = AdversarialMissingness(ConstantFeatures(), lower_bound=20.0).update([25.0, 20.0, 15.0])
    np.testing.assert_allclose(clipped, [0.0, 0.5, 0.5], atol=1e-6)
    uniform = AdversarialMissingness(ConstantFeatures(), mode="uniform")
    np.testing.assert_allclose(uniform.update([25.0, 20.0, 15.0]), 1 / 3)
    worst = AdversarialMissingness(ConstantFeatures(), mode="worst", seed=0)  # the deterministic adversary
    np.testing.assert_array_equal(worst.update([25.0, 20.0, 15.0]), [0.0, 0.0, 1.0])
    assert {tuple(info["hidden"]) for info in (worst.reset()[1] for _ in range(20))} == {(2,)}
    np.testing.assert_array_equal(worst.update([15.0, 20.0, 15.0]), [0.5, 0.0, 0.5])  # ties share
    with pytest.raises(ValueError, match="^mode must be one of adversarial, uniform, worst, got 'Adversarial'$"):
        AdversarialMissingness(ConstantFeatures(), mode="Adversarial")  # would have trained as uniform
    with pytest.raises(ValueError, match="one score per candidate set"):
        env.update([1.0, 2.0])
    with pytest.raises(ValueError, match="lower_bound must be a finite number, got nan"):  # every p_miss NaN
        AdversarialMissingness(ConstantFeatures(), lower_bound=float("nan"))
    with pytest.raises(ValueError, match="epsilon must be > 0 and finite, got inf"):
        AdversarialMissingness(ConstantFeatures(), epsilon=float("inf"))
    with pytest.raises(ValueError, match="epsilon must be > 0 and finite, got 0.0"):  # a zero score's weight 1/0
        AdversarialMissingness(ConstantFeatures(), epsilon=0.0)
    with pytest.raises(ValueError, match="update needs finite scores"):  # a NaN a_u would make every p_miss NaN
        env.update([25.0, float("nan"), 15.0])
    # The constructor's seed fixes the sets drawn at resets without one: the same seed, the same u's.
    def drawn(seed: int) -> list[int]:
        adversary = AdversarialMissingness(ConstantFeatures(), seed=seed)
        adversary.update([25.0, 20.0, 15.0])
        return [adversary.reset()[1]["hidden"][0] for _ in range(20)]
    assert drawn(3) == drawn(3) != drawn(4)

    envs = gymnasium.vector.SyncVectorEnv(
        [lambda seed=seed: AdversarialMissingness(ConstantFeatures(), seed=seed) for seed in range(2)])
    envs.reset(seed=0)
    envs.call("update", [25.0, 20.0, 15.0])
    for p_miss in envs.get_attr("p_miss"):
        np.testing.assert_allclose(p_miss, np.array([12, 15, 20]) / 47, rtol=1e-6)
    envs.close()


def test_wrappers_import_no_jax():
    """Importing the wrappers imports no JAX, nor does a misspelt public name, which is an
    AttributeError as in any module."""
    code = ("import sys, admissable_jax, admissable_jax.wrappers\n"
            "try:\n    admissable_jax.train_fm\nexcept AttributeError as error:\n    print(error)\n"
            "assert 'jax' not in sys.modules, 'jax imported'")
    shown = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert shown.stdout == "module 'admissable_jax' has no attribute 'train_fm'\n"


def test_what_steps_no_mujoco_env_imports_no_mjx():
    """The entry points, configs (physics=warp's too), feature names and the point mass need
    no physics: they import no MJX (with MuJoCo Warp's kernels, about 5 s of a command's
    start on a small CPU)."""
    code = ("import sys; from admissable_jax import audit, config, experiment, plot, train; "
            "from admissable_jax.envs import make_env, observation_names; "
            "config.TrainConfig(env='Ant-v5', physics='warp').resolved(); observation_names('ant'); "
            "make_env('point_mass'); print(sorted(name for name in sys.modules if name.startswith('mujoco.mjx')))")
    shown = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert shown.stdout.strip() == "[]"


@pytest.mark.parametrize("jaxlib, flag_set", [("0.10.2", True), ("0.11.2", False)])
def test_cpu_compile_flag_only_for_the_jaxlib_that_knows_it(jaxlib, flag_set):
    # jaxlib 0.11 aborts at backend start on the XLA:CPU flag that 0.10 compiles faster with.
    code = ("import importlib.metadata as metadata, os; metadata.version = lambda name: " + repr(jaxlib) + "; "
            "import admissable_jax; print('xla_cpu_use_fusion_emitters' in os.environ.get('XLA_FLAGS', ''))")
    env = {key: value for key, value in os.environ.items() if key != "XLA_FLAGS"}
    shown = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env)
    assert shown.stdout.strip() == str(flag_set)
