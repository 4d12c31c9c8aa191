"""Every benchmark script imports, explains itself (``--help``) and refuses bad keys in one
line with exit status 2. Most scripts are run by hand, on a GPU lease or at a size no test
affords; a name they import from the package that moved, a key table that no longer builds,
or a bad key that would start the work (and fail in it, or record nonsense) fails here
instead."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from admissable_jax.envs import EnvState
from admissable_jax.rollout import random_rollout

BENCHMARKS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
IMPORTED_ONLY = {"common.py", "profile_trace.py", "toy_envs.py"}  # modules the scripts import, not commands
HELP_ARGS = {"campaign.py": ["measure", "--help"]}  # its keys follow a verb
PROGRAMS = "hopper, walker2d, ant, point_mass"

# (script, its arguments, the one line it refuses them with, after "error: "): what each
# script checks before it starts (the others' refusals are quoted in the tests that run them).
REFUSALS = [
    ("physics_deviation.py", ["transitions=0"], "transitions must be >= 1, got 0"),
    ("physics_deviation.py", ["num_envs=0"], "num_envs must be >= 1, got 0"),
    ("physics_throughput.py", ["batches=8,0"], "batches and steps must be >= 1"),
    ("physics_throughput.py", ["worlds_per_call=0,-1"], "worlds_per_call must be an int >= 0 (0: from the world's size), got -1"),
    ("physics_throughput.py", ["worlds_per_call=8,all"], "worlds_per_call must be comma-separated ints, got '8,all'"),
    ("program_build.py", ["physics=jax,cuda"], "physics must be comma-separated jax or warp, got 'jax,cuda'"),
    ("program_build.py", ["train=num_envs=-1"], "num_envs must be >= 0, got -1"),
    ("repeatability.py", ["total_steps=100", "learning_starts=100"],
     "learning_starts must be in (0, total_steps = 100), got 100"),
    ("repeatability.py", ["seeds=0"], "seeds must be >= 1, got 0"),
    ("score_estimators.py", [], "give runs=RUN_DIR[,RUN_DIR...]"),
    ("score_estimators.py", ["runs=r", "horizons=0,-3"], "n_episodes must be >= 2 and horizons >= 0"),
    ("score_estimators.py", ["runs=r", "n_episodes=1"], "n_episodes must be >= 2 and horizons >= 0"),
    ("scoring_round.py", ["slots=-2"], "slots must be -1 (the backend's default), 0 (all episodes) or >= 1, got -2"),
    ("set_search.py", ["repeats=0"], "repeats must be >= 1, got 0"),
    ("set_search.py", ["d=-1"], "d must be >= 1, got -1"),
    ("shapley_orders.py", ["audit={tmp}/audit.json"],
     "{tmp}/audit.json holds no exact Shapley attribution with its coalition values (audit shapley=exact)"),
    ("shapley_orders.py", ["audit={tmp}/audit.json", "repeats=0"], "repeats must be >= 1, got 0"),
    ("sharding_scaling.py", ["num_envs=0"], "num_envs must be >= 1, got 0"),
    ("sharding_scaling.py", ["pairs=0"], "pairs must be >= 1, got 0"),
    ("sim_to_sim.py", [], "run= is required (a run directory)"),
    ("sim_to_sim.py", ["run=r", "best=true", "step=5"], "best=true scores the policy the run kept at its best scoring: "
                                                        "give no step="),
    ("startup_time.py", ["repeats=0"], "repeats must be >= 1, got 0"),
    ("step_compile.py", ["steps=0"], "batch and steps must be >= 1"),
    ("stop_latency.py", ["seeds=0"], "seeds must be >= 1, got 0"),
    ("stop_latency.py", ["after=-1"], "after must be >= 0 seconds, got -1.0"),
    ("train_throughput.py", ["set_rows=listed"], "set_rows must be auto or computed, got 'listed'"),
    ("train_throughput.py", ["num_envs=0"], "num_envs must be >= 1, got 0"),
    ("train_throughput.py", ["iterations=0"], "iterations must be >= 1, got 0"),
    ("warp_atomics.py", ["steps=-1"], "num_envs must be >= 1 and steps >= 0, got 4 and -1"),
    ("warp_cpu_compile.py", ["levels=0,4"], "levels must be a comma list of 0, 1, 2, 3, got '0,4'"),
    ("warp_cpu_compile.py", ["worlds=0"], "repeats, worlds and steps must be >= 1"),
    ("warp_kernels.py", ["arch=70"], "arch must be a CUDA architecture Warp supports (>= 75), got 70"),
    ("warp_kernels.py", ["batch=0"], "batch must be >= 1"),
    ("warp_launches.py", ["solver_iterations=4,x"], "solver_iterations must be a comma list of ints >= 0, got '4,x'"),
    ("warp_launches.py", ["num_envs=0"], "num_envs must be >= 1, got 0"),
    ("xla_cpu_compile.py", ["programs=hopper,cheetah"], f"programs must be a comma list of {PROGRAMS} and repeats >= 1"),
    ("xla_cpu_compile.py", ["flag_sets=--a||--b"], "flag_sets must be XLA_FLAGS settings separated by |, none empty"),
    ("compact_pngs.py", [], "give the PNG files, notebooks or folders to compact: python benchmarks/compact_pngs.py PATH [PATH ...]"),
    ("load_policy_memory.py", [], "give one run directory (a train run's or an experiment pair's)"),
]

# One process for all runs (each script imports JAX, some Brax or SciPy): each script run as
# ``__main__`` with its arguments, its exit status (or the traceback that stopped it) and what
# it printed.
CHILD = """
import contextlib, io, json, runpy, sys, traceback
sys.path.insert(0, sys.argv[1])
results = []
for script, args in json.loads(sys.argv[2]):
    sys.argv = [script, *args]
    printed, status = io.StringIO(), 0
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        try:
            runpy.run_path(f"{sys.path[0]}/{script}", run_name="__main__")
        except SystemExit as stop:
            status = stop.code or 0
        except Exception:  # an import that fails: the script is named with its traceback
            status = traceback.format_exc()
    results.append([status, printed.getvalue()])
print(json.dumps(results))
"""


def test_every_benchmark_script_imports_explains_itself_and_refuses_bad_keys(tmp_path):
    scripts = sorted(name for name in os.listdir(BENCHMARKS) if name.endswith(".py") and name not in IMPORTED_ONLY)
    assert {"sim_to_sim.py", "score_estimators.py", "step_compile.py", "brax_sac.py"} <= set(scripts)
    (tmp_path / "audit.json").write_text(json.dumps({"shapley": {"method": "sampled"}}))
    refusals = [(script, [arg.format(tmp=tmp_path) for arg in args], message.format(tmp=tmp_path))
                for script, args, message in REFUSALS]
    runs = [(name, HELP_ARGS.get(name, ["--help"])) for name in scripts] + [(script, args) for script, args, _ in refusals]
    child = subprocess.run([sys.executable, "-c", CHILD, BENCHMARKS, json.dumps(runs)], capture_output=True, text=True,
                           timeout=300, cwd=tmp_path, env={**os.environ, "BENCHMARK_RESULTS_DIR": str(tmp_path / "results")})
    assert child.returncode == 0, child.stderr[-3000:]
    results = json.loads(child.stdout.strip().splitlines()[-1])
    for name, (status, printed) in zip(scripts, results):
        assert status == 0, (name, printed[-2000:])
        assert f"benchmarks/{name}" in printed, (name, printed[:500])  # its usage line, or its docstring's example
    for (script, args, message), (status, printed) in zip(refusals, results[len(scripts):]):
        assert (status, printed) == (2, f"error: {message}\n"), (script, args)
    assert not (tmp_path / "results").exists()  # nothing recorded


class _PhysicsOnly:
    """An env whose step is its physics' alone (the data moves by the action; never done), so a
    rollout of it and the bare physics under the same actions end in the same data."""

    action_size = 3
    action_low, action_high = -jnp.ones(3), 2 * jnp.ones(3)
    physics = SimpleNamespace(step=lambda data, action: data + action)

    def reset(self, rng):
        return self._state(jax.random.uniform(rng, (self.action_size,)))

    def step(self, state, action):
        return self._state(self.physics.step(state.data, action))

    @staticmethod
    def _state(data):
        false = jnp.zeros((), bool)
        return EnvState(data=data, obs=data, reward=jnp.sum(data), terminated=false, truncated=false,
                        step_count=jnp.zeros((), jnp.int32), metrics={}, episode_metrics={})


def test_physics_throughput_times_the_bare_physics_under_the_env_rollouts_actions():
    """env/bare is our env layer's cost only if both step the same physics: the bare rollout
    starts from the env rollout's states and takes its random actions (zero controls timed
    another solve: Walker2d's env/bare read 1.50 on a CPU where it is 1.03)."""
    import physics_throughput

    env, rng = _PhysicsOnly(), jax.random.key(3)
    states, _ = random_rollout(env, 4, 5, rng)
    bare = physics_throughput._bare_rollout(env, 4, 5, rng)
    np.testing.assert_allclose(bare, states.data, rtol=1e-6)
