"""An env of one's own (``env=package.module:Class``, :mod:`admissable_jax.envs.external`):
named by its import path, it trains, resumes in another process, is plotted and audited as
ours are. The envs are the README's examples (``benchmarks/toy_envs.py``'s ``Reach`` and
``tests/own_envs.py``'s ``BraxFast``); pure JAX, so seconds to compile."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import own_envs
import toy_envs  # benchmarks/ is on the tests' path (conftest.py)
from admissable_jax import TrainConfig, make_env, train_fn
from admissable_jax.audit import main as audit_main
from admissable_jax.envs import observation_names
from admissable_jax.plot import main as plot_main
from admissable_jax.train import main as train_main

NAME = "toy_envs:Reach"
SHORT = ["score_every=200", "num_envs=4", "learning_starts=200", "episode_length=20", "batch_size=32",
         "hidden_size=32", "score_episodes=3", "checkpoint_every=1", "progress=false"]


def test_the_readmes_envs_are_the_ones_tested():
    """The README's two examples are ``benchmarks/toy_envs.py``'s code and ``BraxFast``'s,
    word for word."""
    readme = open(os.path.join(os.path.dirname(__file__), "..", "README.md")).read()
    section = readme.split("### Your own env: `env=package.module:Class`")[1].split("\n## ")[0]
    own, brax = (block.split("```")[0].strip() for block in section.split("```python\n")[1:3])
    assert own in open(toy_envs.__file__).read() and "class DistractedReach(Reach)" in own
    assert brax in open(own_envs.__file__).read() and brax.startswith("class BraxFast(BraxEnv)")


def test_an_env_of_ones_own_trains_resumes_plots_and_is_audited(tmp_path, capsys):
    env = make_env(NAME, episode_length=20)
    assert (env.name, env.observation_size, env.action_size, env.physics_name) == (NAME, 3, 1, "jax")
    assert observation_names(NAME) == ["position", "velocity", "goal"]
    assert TrainConfig(env=NAME).resolved().out == "runs/reach-adversarial-s0"
    with pytest.raises(TypeError, match="^env must be a name: env=toy_envs:Reach names this class$"):
        TrainConfig(env=toy_envs.Reach).resolved()  # the class itself: its name is what a run keeps
    with pytest.raises(TypeError, match="^env name must be a string, got int$"):
        make_env(123)
    # Options: EnvOptions fields as keywords; a dict for the EnvOptions, or a field misspelt,
    # is one line (before: an env holding the dict, or EnvOptions' own TypeError).
    with pytest.raises(TypeError, match=r"^options must be an EnvOptions, got dict \(a dict's keys go as keywords: "
                                        r"make_env\(name, \*\*options\)\)$"):
        make_env(NAME, {"episode_length": 20})
    with pytest.raises(TypeError, match="^make_env got an unknown option 'episode_lenght'; the options are "
                                        "episode_length, physics, "):
        make_env(NAME, episode_lenght=20)
    # The state the base class fills in: one step by hand, then truncation at episode_length.
    start = env.reset(jax.random.key(1))
    position, _, goal = np.asarray(start.obs)
    after = env.step(start, jnp.ones(1))
    np.testing.assert_allclose(after.obs, [position + 0.01, 0.1, goal], rtol=1e-6)
    np.testing.assert_allclose(after.reward, np.exp(-(position + 0.01 - goal) ** 2), rtol=1e-6)
    assert int(after.step_count) == 1 and not bool(after.done)
    np.testing.assert_allclose(after.episode_metrics["return"], after.reward)
    last = jax.lax.fori_loop(0, 20, lambda _, state: env.step(state, jnp.zeros(1)), start)
    assert bool(last.truncated) and not bool(last.terminated) and int(last.step_count) == 20

    # A command in a process of its own finds the class by its name (PYTHONPATH), trains and
    # keeps the name in config.yaml; train_fn here resumes it from there.
    out = str(tmp_path / "reach")
    command = subprocess.run([sys.executable, "-m", "admissable_jax.train", f"env={NAME}", "total_steps=400",
                              f"out={out}", *SHORT], capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), *sys.path])})
    assert command.returncode == 0, command.stderr
    assert command.stdout.startswith(f"done: {NAME} adversarial seed 0, 400 env steps")
    assert f"env: {NAME}\n" in open(os.path.join(out, "config.yaml")).read()
    resumed = train_fn(TrainConfig(env=NAME, total_steps=600, out=out, resume=True, score_every=200, num_envs=4,
                                   learning_starts=200, episode_length=20, batch_size=32, hidden_size=32,
                                   score_episodes=3, progress=False))
    assert [row["env_steps"] for row in resumed.scores] == [200, 400, 600]
    for row in resumed.scores:
        assert len(row["scores"]) == 3 and row["min_score"] == min(row["scores"])
        assert row["argmin_set"] in ("{0}", "{1}", "{2}")

    # plot and the audit name the features as the class does.
    assert plot_main([out, f"out={tmp_path / 'figures'}", "formats=png"]) == 0
    with open(tmp_path / "figures" / "scores.csv") as file:
        assert {row["hidden"] for row in csv.DictReader(file)} == {"position", "velocity", "goal"}
    assert audit_main([out, "episodes=4", f"out={tmp_path / 'audit'}"]) == 0
    with open(tmp_path / "audit" / "audit.json") as file:
        assert sorted(entry["names"][0] for entry in json.load(file)["sets"]["1"]) == ["goal", "position", "velocity"]
    # Read back where the env's code is not (its module named away): plot names the features
    # as the run recorded them (observation_names.json).
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(out, elsewhere, ignore=shutil.ignore_patterns("checkpoints"))
    config_yaml = elsewhere / "config.yaml"
    config_yaml.write_text(config_yaml.read_text().replace(f"env: {NAME}\n", "env: gone_envs:Reach\n"))
    assert plot_main([str(elsewhere), f"out={tmp_path / 'figures_elsewhere'}", "formats=png"]) == 0
    with open(tmp_path / "figures_elsewhere" / "scores.csv") as file:
        assert {row["hidden"] for row in csv.DictReader(file)} == {"position", "velocity", "goal"}
    capsys.readouterr()


@pytest.mark.parametrize("name, said", [
    ("own_envs:Nope", "env 'own_envs:Nope': own_envs has no class Nope"),
    ("no_such_module:Env", "env 'no_such_module:Env': cannot import no_such_module (ModuleNotFoundError: No module "
                           "named 'no_such_module')"),
    ("own_envs:NotAnEnv",
     "env 'own_envs:NotAnEnv': NotAnEnv must define reset and step (subclass envs.ExternalEnv)"),
    ("own_envs:NoSize", "env 'own_envs:NoSize': NoSize.observation_size must be an int >= 1, got None"),
    ("own_envs:NoFeatures", "env 'own_envs:NoFeatures': NoFeatures.observation_size must be an int >= 1, got 0"),
    ("own_envs:OneName", "env 'own_envs:OneName': OneName.feature_names holds 1 names; its observations have "
                          "3 entries"),
    # Found, but its observations are not as long as it says: seen when the programs are traced.
    ("own_envs:WrongObservation",
     "WrongObservation gives observations of shape (3,), not (4,) (its observation_size)"),
])
def test_a_name_that_leads_to_no_usable_env_is_one_line(name, said, tmp_path, capsys):
    assert train_main([f"env={name}", f"out={tmp_path / 'x'}", *SHORT]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"error: {said}"
    assert not (tmp_path / "x").exists()


def test_a_run_records_the_physics_that_steps_its_env(monkeypatch):
    """On a GPU with warp-lang, physics=auto is warp for a MuJoCo env; an env without a
    MuJoCo model steps in JAX whatever is chosen, and its config says so (it said warp)."""
    from admissable_jax.envs import options

    monkeypatch.setattr(options, "_on_nvidia_gpu", lambda: True)
    monkeypatch.setattr(options, "warp_installed", lambda: True)
    assert TrainConfig(env="hopper").resolved().physics == "warp"
    for env in ("point_mass", "own_envs:BraxFast"):
        assert [TrainConfig(env=env, physics=physics).resolved().physics for physics in ("auto", "warp")] == ["jax"] * 2
    with pytest.raises(ValueError, match="physics must be one of auto, jax, warp, got 'cuda'"):
        TrainConfig(env="point_mass", physics="cuda").resolved()
    # warp-lang installed on a machine without an NVIDIA GPU: auto is MJX's JAX (Warp's CPU
    # kernels step at ~70 ms a batch), and warp only where asked for.
    monkeypatch.setattr(options, "_on_nvidia_gpu", lambda: False)
    assert [TrainConfig(env="hopper", physics=physics).resolved().physics for physics in ("auto", "warp")] == [
        "jax", "warp"]


def test_the_benchmarks_distracted_reach_hides_its_signal_among_noise():
    """benchmarks/toy_envs.py's DistractedReach (its runs: benchmarks/README.md): position,
    velocity and goal as Reach's, then 17 features of fresh noise each step."""
    env = make_env("toy_envs:DistractedReach", episode_length=20)  # benchmarks/ is on the tests' path
    assert observation_names(env.name)[:4] == ["position", "velocity", "goal", "noise 0"] and env.observation_size == 20
    start = env.reset(jax.random.key(2))
    after = env.step(start, jnp.ones(1))
    position, _, goal = np.asarray(start.obs[:3])
    np.testing.assert_allclose(after.obs[:3], [position + 0.01, 0.1, goal], rtol=1e-6)
    np.testing.assert_allclose(after.reward, np.exp(-(position + 0.01 - goal) ** 2), rtol=1e-6)
    again = env.step(after, jnp.ones(1))
    assert np.all(np.asarray(after.obs[3:]) != np.asarray(again.obs[3:]))  # the noise is drawn afresh
    assert 0.5 < float(np.std(np.asarray(again.obs[3:]))) < 2.0
    # action_bound sets the box the trainer's tanh is scaled to and random actions are drawn from.
    wide = make_env("own_envs:WideReach")
    np.testing.assert_array_equal([wide.action_low, wide.action_high], [[-2.0], [2.0]])


def test_the_point_mass_steps_as_its_docstring_says():
    """The point mass (the tests' and smoke runs' env) by hand: velocity + 0.1 · force
    (clipped to [-1, 1]), position + 0.1 · the new velocity, the reward exp(-|p|²) at the
    position the step reaches, termination past radius 3."""
    env = make_env("point_mass")
    start = env.reset(jax.random.key(0))
    reached = np.asarray(start.obs[:2]) + [0.01, -0.01]
    after = env.step(start, jnp.array([1.0, -2.0]))
    np.testing.assert_allclose(after.obs, [*reached, 0.1, -0.1], rtol=1e-6)
    np.testing.assert_allclose(after.reward, np.exp(-np.sum(reached**2)), rtol=1e-6)
    leaving = start.replace(data=start.data.replace(position=jnp.array([2.995, 0.0]), velocity=jnp.array([1.0, 0.0])))
    assert not bool(after.terminated) and bool(env.step(leaving, jnp.zeros(2)).terminated)  # at x = 3.095


def test_a_brax_env_takes_part_by_its_name_and_sizes(tmp_path, capsys):
    """Brax's test env "fast" through BraxEnv: one step by hand (velocity + 0.02 while the
    action is positive, position + 0.02 · velocity, reward = position), Brax's done as the
    termination (unless terminate_when_unhealthy=False), a short run scoring both features,
    and sizes stated wrong said in one line."""
    env = make_env("own_envs:BraxFast", episode_length=20)
    after = env.step(env.reset(jax.random.key(0)), jnp.ones(1))
    np.testing.assert_allclose(after.obs, [0.0004, 0.02], rtol=1e-6)
    np.testing.assert_allclose([after.reward, after.episode_metrics["return"]], [0.0004, 0.0004], rtol=1e-6)
    assert not bool(after.done) and int(after.step_count) == 1
    # Brax's done is the termination; with terminate_when_unhealthy=False (Gymnasium's
    # argument) the episode runs on to its time limit instead.
    for terminates in (True, False):
        finish = make_env("own_envs:BraxFastFinish", episode_length=20, terminate_when_unhealthy=terminates)
        first = finish.step(finish.reset(jax.random.key(0)), jnp.ones(1))  # position 0.0004: short of 0.001
        second = finish.step(first, jnp.ones(1))  # 0.0012: past it
        assert [bool(first.terminated), bool(second.terminated), bool(second.truncated)] == [False, terminates, False]
    run = train_fn(TrainConfig(env="own_envs:BraxFast", total_steps=400, out=str(tmp_path / "fast"), score_every=200,
                               num_envs=4, learning_starts=200, episode_length=20, batch_size=32, hidden_size=32,
                               score_episodes=3, progress=False))
    assert [len(row["scores"]) for row in run.scores] == [2, 2]
    assert train_main(["env=own_envs:WrongSize", f"out={tmp_path / 'wrong'}"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "error: WrongSize states observation_size 3 and action_size 1; the env it builds has 2 and 1")
    assert not (tmp_path / "wrong").exists()
