"""Our MJX envs against Gymnasium's C-MuJoCo v5 envs, on both physics backends.

Parity: from (qpos, qvel) visited by Gymnasium under random actions, one of our steps and
one of Gymnasium's, with the same action, give the same obs, reward and termination. We
run in float32 and Gymnasium in float64, so we allow small absolute errors (per env below).
Every parity test runs on MJX's JAX implementation and on MuJoCo Warp (on the CPU here).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import importlib.metadata
import math
import os
import subprocess
import sys
import types

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import make_env
from admissable_jax.envs import MAX_EPISODE_STEPS, EnvOptions, contact_frames, settotalmass_warning_dropped
from admissable_jax.envs.parity import gymnasium_transitions, step_from_state
from admissable_jax.envs.physics import in_one_flat_batch

ENV_NAMES = ("hopper", "walker2d", "ant", "halfcheetah")
TERMINATING_ENV_NAMES = ("hopper", "walker2d", "ant")  # HalfCheetah has no health rule
# Warp first: its CPU kernels are built once per machine, and built here first they are on
# disk before the other test worker's Warp experiment needs the same ones.
BACKENDS = ("warp", "jax")
ENV_BACKENDS = [(name, physics) for physics in BACKENDS for name in ENV_NAMES]
N_TRANSITIONS = 120
N_RESETS = 4096

# Largest |ours - Gymnasium| allowed on an observation entry. Measured maxima over 100
# transitions: Hopper 4e-6, Walker2d 1.2e-4, Ant 1.9e-4 (all in clipped joint velocities,
# where float32 round-off over 4-5 RK4 substeps with contact shows). Walker2d and Ant get
# 5e-4, about 4x their measured maximum; a changed weight, clip or term moves entries by
# far more (Ant without the contact-frame fix is off by 2.0). HalfCheetah's velocities are
# not clipped (up to 92 in these 120 transitions) and its errors are the largest: 5.8e-4 on
# the obs, 1.1e-3 on the reward (x velocity); MJX in float64 matches Gymnasium to 2e-12 on
# 400 such transitions, so they are float32 round-off. It gets about 4x too.
OBS_TOLERANCE = {"hopper": 1e-4, "walker2d": 5e-4, "ant": 5e-4, "halfcheetah": 2.5e-3}
# Measured maxima 4e-6 (Hopper), 4e-6 (Walker2d), 7e-6 (Ant), 1.1e-3 (HalfCheetah).
REWARD_TOLERANCE = {"hopper": 1e-4, "walker2d": 1e-4, "ant": 1e-4, "halfcheetah": 5e-3}


@pytest.fixture(scope="module", params=ENV_BACKENDS, ids=lambda p: "-".join(p))
def env_case(request):
    """(env, Gymnasium transitions, our batched step from the same states, 4096 resets), from
    one compiled program per env and backend."""
    name, physics = request.param
    env = make_env(name, physics=physics, max_batch=N_RESETS)
    assert env.physics_name == physics
    gym = gymnasium_transitions(env.gymnasium_id, N_TRANSITIONS)
    # Step counts spread so that some transitions reach the 1000-step limit.
    step_counts = np.arange(N_TRANSITIONS, dtype=np.int32) % 4 + (MAX_EPISODE_STEPS - 3)
    step_counts[: N_TRANSITIONS // 2] = 0

    def resets_and_steps(keys, qpos, qvel, action, counts):
        step = jax.vmap(functools.partial(step_from_state, env))
        return jax.vmap(env.reset)(keys), step(qpos, qvel, action, counts)

    resets, ours = jax.jit(resets_and_steps)(
        jax.random.split(jax.random.key(0), N_RESETS), gym["qpos"], gym["qvel"], gym["action"], step_counts
    )
    return env, gym, ours, step_counts, resets


def test_step_parity_with_gymnasium(env_case):
    env, gym, ours, step_counts, _ = env_case
    name = env.name

    # The sample must exercise what the test guards: terminations, and the clipping.
    if name in TERMINATING_ENV_NAMES:
        assert gym["terminated"].any(), "no termination among the sampled transitions"
    if name == "halfcheetah":  # velocities far beyond the walkers' clip stay unclipped
        assert (np.abs(gym["obs"][:, env.mj_model.nq - 1 :]) > 20.0).any()
    elif name == "ant":
        contact = gym["obs"][:, 27:]
        assert (np.abs(contact) == 1.0).any(), "no clipped contact force in the sample"
        assert (gym["info_reward_contact"] < 0).any()
    else:
        velocities = gym["obs"][:, env.mj_model.nq - 1 :]
        assert (np.abs(velocities) == 10.0).any(), "no clipped joint velocity in the sample"

    obs_error = np.abs(np.asarray(ours.obs) - gym["obs"])
    assert obs_error.max() <= OBS_TOLERANCE[name], (obs_error.max(), obs_error.max(0).argmax())
    np.testing.assert_allclose(np.asarray(ours.reward), gym["reward"], rtol=0, atol=REWARD_TOLERANCE[name])
    np.testing.assert_array_equal(np.asarray(ours.terminated), gym["terminated"])

    # Each reward term and position in the metrics matches Gymnasium's info.
    for key in (*env.reward_terms, *env.info_keys):
        np.testing.assert_allclose(
            np.asarray(ours.metrics[key]), gym[f"info_{key}"], rtol=1e-5, atol=REWARD_TOLERANCE[name],
            err_msg=key,
        )
    terms_sum = sum(np.asarray(ours.metrics[key]) for key in env.reward_terms)
    np.testing.assert_allclose(terms_sum, np.asarray(ours.reward), atol=1e-5)
    np.testing.assert_allclose(np.asarray(ours.episode_metrics["return"]), np.asarray(ours.reward))

    # Truncation: exactly when the step counter reaches the 1000-step limit.
    np.testing.assert_array_equal(np.asarray(ours.step_count), step_counts + 1)
    np.testing.assert_array_equal(
        np.asarray(ours.truncated), step_counts + 1 >= MAX_EPISODE_STEPS
    )
    assert np.asarray(ours.truncated).any() and not np.asarray(ours.truncated).all()

    if env.physics_name == "warp":
        _assert_unbatched_step_matches_batched(env, gym, ours, step_counts)


def test_contact_frame_patches_are_installed_and_current():
    """Both backends' plane–capsule colliders are ours, and the upstream code they replace is
    the code they were written against: a MuJoCo upgrade that changes it fails here."""
    from admissable_jax.envs import Hopper  # noqa: F401  (an env class's import imports the physics, which installs both)

    assert contact_frames.is_installed() and contact_frames.is_installed_warp()
    assert contact_frames.upstream_source_hashes() == contact_frames.PATCHED_SOURCES, (
        "MuJoCo changed the plane-capsule collider our contact_frames patch replaces: re-check "
        "Ant parity without the patch, then drop or update it and PATCHED_SOURCES"
    )


# The kernels of a Hopper, Walker2d or Ant step that keep float atomics outside RUN_TO_RUN mode,
# each read (benchmarks/README.md, *Could a run continue*): every thread updates elements of its
# own, so no element's sum depends on the order of the threads.
OWN_ELEMENT_FLOAT_ATOMICS = {"_M", "_apply_ft", "_linesearch_iterative_kernel__locals__kernel",
                             "_rk_accumulate_velocity_acceleration", "_update_gradient_h_incremental"}


def test_warp_steps_the_mujoco_warp_package_deterministically():
    """MJX's Warp bridge runs the mujoco-warp package in its deterministic mode: an Ant step
    launches kernels built in Warp's RUN_TO_RUN mode (atomic sums and atomic slot counters
    made run-to-run invariant), its collision and constraint-row kernels among them. Outside
    that mode no kernel takes slots from an atomic counter, and float atomics stay in the
    kernels read to update elements of their own threads (the C++ Warp generated, read by
    benchmarks/warp_atomics.py). A second setting in one process is refused."""
    import warp
    import warp_atomics  # benchmarks/ is on the tests' path (conftest.py)
    import warp_launches

    from admissable_jax.envs import warp_package

    env = make_env("ant", physics="warp", max_batch=N_RESETS)  # the parity test's kernels
    assert warp_package.runs_package()
    kernels, launches, empty = warp_launches.launched_kernels(
        warp, jax.jit(env.step), env.reset(jax.random.key(1)), jnp.zeros(env.action_size))
    run_to_run = {key for key, kernel in kernels.items()
                  if kernel.module.options.get("deterministic") == warp.DeterministicMode.RUN_TO_RUN}
    assert sum(launches[key] for key in run_to_run) >= 10, launches
    # The collision and constraint kernels too (the package leaves them out): contact slots,
    # and each contact's and joint limit's rows in efc, in a fixed order.
    assert {"_nxn_broadphase__locals__kernel", "_primitive_narrowphase__locals__primitive_narrowphase",
            "_efc_contact_init__locals__kernel", "_limit_slide_hinge__locals__kernel"} <= run_to_run
    kinds = collections.defaultdict(set)
    for key in set(kernels) - run_to_run - empty:
        for atomic in warp_atomics.atomics_of(key, warp_atomics.generated_source(warp, kernels[key])):
            kinds[atomic["kind"]].add(key)
    assert not kinds["slot counter"] and kinds["float"] == OWN_ELEMENT_FLOAT_ATOMICS, dict(kinds)
    with pytest.raises(ValueError, match="one setting per process"):
        make_env("hopper", physics="warp", deterministic=False)


def test_mjx_keeps_its_own_warp_when_asked_or_given_another_release():
    """ADMISSABLE_MJX_OWN_WARP=1 (the GPU campaign's fallback): MJX runs its own MuJoCo Warp, a
    deterministic env is refused in one line, a non-deterministic one builds. A mujoco-warp of
    another release than mujoco-mjx's is not put in MJX's place, and the refusal names both."""
    script = (
        "from admissable_jax import make_env\n"
        "from admissable_jax.envs import warp_package\n"
        "try:\n"
        "    make_env('hopper', physics='warp')\n"
        "except ValueError as error:\n"
        "    print('refused:', error)\n"
        "make_env('hopper', physics='warp', deterministic=False)\n"
        "import mujoco.mjx.third_party.mujoco_warp as warp_in_mjx\n"
        "print('package:', warp_package.runs_package(), warp_in_mjx.__name__)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env={**os.environ, "ADMISSABLE_MJX_OWN_WARP": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "refused: deterministic_physics=true needs the mujoco-warp package" in done.stdout
    assert "package: False mujoco.mjx.third_party.mujoco_warp" in done.stdout

    another_release = (
        "import importlib.metadata as metadata\n"
        "installed = metadata.version\n"
        "metadata.version = lambda name: '4.0.0' if name == 'mujoco-warp' else installed(name)\n"
        "from admissable_jax.envs import physics, warp_package  # physics imports MJX\n"
        "print('package:', warp_package.runs_package())\n"
        "warp_package.set_deterministic(True)\n"
    )
    done = subprocess.run([sys.executable, "-c", another_release], capture_output=True, text=True)
    assert done.returncode == 1 and "package: False" in done.stdout, done.stdout + done.stderr[-2000:]
    mjx = importlib.metadata.version("mujoco-mjx")
    assert (f"ValueError: deterministic_physics=true needs the mujoco-warp package imported before MJX (mujoco-warp "
            f"4.0.0 is not mujoco-mjx {mjx}'s release (pip install mujoco-warp=={mjx}, or the 'cuda' extra)), "
            "or deterministic_physics=false") in done.stderr


def test_reset_distribution_and_observation(env_case):
    env, *_, states = env_case
    scale = env.reset_noise_scale
    qpos_noise = np.asarray(states.data.qpos) - np.asarray(env.init_qpos)
    qvel_noise = np.asarray(states.data.qvel) - np.asarray(env.init_qvel)
    # qpos noise ~ U(-s, s) in every env: bounded, mean 0, std s/sqrt(3).
    assert np.abs(qpos_noise).max() <= scale * (1 + 1e-5)
    np.testing.assert_allclose(qpos_noise.std(0), scale / math.sqrt(3), rtol=0.06)
    np.testing.assert_allclose(qpos_noise.mean(0), 0.0, atol=0.05 * scale)
    if env.name in ("ant", "halfcheetah"):  # qvel noise ~ s * N(0, 1), unbounded
        np.testing.assert_allclose(qvel_noise.std(0), scale, rtol=0.06)
        assert np.abs(qvel_noise).max() > 2 * scale
    else:
        assert np.abs(qvel_noise).max() <= scale * (1 + 1e-5)
        np.testing.assert_allclose(qvel_noise.std(0), scale / math.sqrt(3), rtol=0.06)
    # Independent draws per key.
    assert len(np.unique(qpos_noise, axis=0)) == len(qpos_noise)
    assert not np.asarray(states.done).any()
    assert (np.asarray(states.step_count) == 0).all()

    # The reset observation is Gymnasium's for the same (qpos, qvel).
    with settotalmass_warning_dropped():
        gym_env = gymnasium.make(env.gymnasium_id)
    gym_env.reset(seed=0)
    for i in range(5):
        qpos = np.asarray(states.data.qpos[i], np.float64)
        qvel = np.asarray(states.data.qvel[i], np.float64)
        gym_env.unwrapped.set_state(qpos, qvel)
        np.testing.assert_allclose(
            np.asarray(states.obs[i]), gym_env.unwrapped._get_obs(), rtol=1e-5, atol=1e-6
        )
    gym_env.close()


def _boundary_states(env) -> list[tuple[np.ndarray, np.ndarray]]:
    """States on both sides of each health boundary (1e-4 away: float32 rounds exact ties)."""
    base_qpos = np.asarray(env.init_qpos, np.float64)
    base_qvel = np.zeros(env.mj_model.nv)
    eps = 1e-4
    states = []

    def with_qpos(index, value):
        qpos = base_qpos.copy()
        qpos[index] = value
        states.append((qpos, base_qvel.copy()))

    if env.name == "ant":
        for z in (0.2 - eps, 0.2, 0.2 + eps, 1.0 - eps, 1.0, 1.0 + eps):
            with_qpos(2, z)
        nan_qvel = base_qvel.copy()
        nan_qvel[3] = np.nan
        states.append((base_qpos.copy(), nan_qvel))
    else:
        for z_bound in env.healthy_z_range:
            if math.isfinite(z_bound):
                for z in (z_bound - eps, z_bound + eps):
                    with_qpos(1, z)
        for angle_bound in env.healthy_angle_range:
            for angle in (angle_bound - eps, angle_bound + eps):
                with_qpos(2, angle)
    if env.name == "hopper":
        for value in (99.99, 100.01, -100.01):
            qvel = base_qvel.copy()
            qvel[4] = value
            states.append((base_qpos.copy(), qvel))
        qpos = base_qpos.copy()
        qpos[4] = -100.01
        states.append((qpos, base_qvel.copy()))
    return states


@pytest.mark.parametrize("name", TERMINATING_ENV_NAMES)
def test_health_rules_match_gymnasium_at_their_boundaries(name):
    env = make_env(name)
    with settotalmass_warning_dropped():
        gym_env = gymnasium.make(env.gymnasium_id)
    gym_env.reset(seed=0)
    ours, theirs = [], []
    for qpos, qvel in _boundary_states(env):
        ours.append(bool(env.is_healthy(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))))
        gym_env.unwrapped.data.qpos[:] = qpos
        gym_env.unwrapped.data.qvel[:] = qvel
        theirs.append(bool(gym_env.unwrapped.is_healthy))
    gym_env.close()
    assert ours == theirs
    assert any(ours) and not all(ours)


def test_a_fallen_hopper_terminates_unless_told_not_to(monkeypatch):
    """Gymnasium's ``terminate_when_unhealthy=False`` (the benchmarks' full-length rounds): a
    fallen Hopper steps on, without the survive bonus; by default it terminates. The rule
    alone, eagerly: the physics is held still (its parity is the tests' above)."""
    fallen = np.array(make_env("hopper").init_qpos, np.float32)
    fallen[1] = 0.5  # z below 0.7
    for terminates in (True, False):
        env = make_env("hopper", physics="jax", terminate_when_unhealthy=terminates)
        monkeypatch.setattr(env.physics, "data", lambda qpos, qvel: types.SimpleNamespace(qpos=qpos, qvel=qvel))
        monkeypatch.setattr(env.physics, "step", lambda data, action: data)
        state = env.state_from_qpos_qvel(fallen, np.zeros(env.mj_model.nv, np.float32))
        stepped = env.step(state, jnp.zeros(env.action_size))
        assert bool(stepped.terminated) == terminates and float(stepped.metrics["reward_survive"]) == 0.0


def _assert_unbatched_step_matches_batched(env, gym, batched, step_counts):
    """Warp shares scratch buffers across a batch's worlds: one world stepped alone must give
    what it gives inside the batch. (On MJX's JAX implementation vmap is JAX's own
    transformation of pure code; the batching that is ours to get right is Warp's.)"""
    step = jax.jit(functools.partial(step_from_state, env))
    for i in (0, 7, 31, N_TRANSITIONS - 1):
        single = step(gym["qpos"][i], gym["qvel"][i], gym["action"][i], step_counts[i])
        np.testing.assert_allclose(np.asarray(single.obs), np.asarray(batched.obs[i]), atol=1e-5)
        np.testing.assert_allclose(float(single.reward), float(batched.reward[i]), atol=1e-5)
        assert bool(single.done) == bool(batched.done[i])


def test_one_flat_batch_under_nested_vmap():
    """``in_one_flat_batch``: however deep the vmaps, the wrapped function is vmapped once, over
    all their members in row-major order (an FFI call sees one flat batch), unbatched inputs
    reach every member, and each member's result is the function's."""
    seen_batches = []

    def world(x, scale):  # a host callback stands in for the FFI: it sees the batch it is given
        def host(x, scale):
            seen_batches.append(x.shape[:-1])
            return (x * scale[..., None]).astype(x.dtype)

        return jax.pure_callback(host, jax.ShapeDtypeStruct(x.shape, x.dtype), x, scale, vmap_method="broadcast_all")

    x = jnp.arange(2 * 3 * 4 * 5, dtype=jnp.float32).reshape(2, 3, 4, 5)
    scale = jnp.asarray([1.0, 2.0, 3.0, 4.0])
    out = jax.jit(jax.vmap(jax.vmap(jax.vmap(in_one_flat_batch(world), in_axes=(0, 0)), in_axes=(0, None)),
                           in_axes=(0, None)))(x, scale)
    assert seen_batches == [(24,)]
    np.testing.assert_array_equal(np.asarray(out), np.asarray(x * scale[:, None]))
    assert np.asarray(in_one_flat_batch(world)(x[0, 0, 0], scale[0])).tolist() == np.asarray(x[0, 0, 0]).tolist()
    assert seen_batches[-1] == ()
    # In pieces (the JAX physics on a CPU): 24 worlds at most 5 a call are 5 even pieces of 5,
    # one after another, the last padded with a copy of the last world; each keeps its result.
    seen_batches.clear()
    pieces = jax.jit(jax.vmap(jax.vmap(in_one_flat_batch(world, worlds_per_call=5), in_axes=(0, None))))
    out = pieces(x.reshape(6, 4, 5), scale[0] + jnp.arange(6.0))
    assert seen_batches == [(5,)] * 5
    np.testing.assert_array_equal(np.asarray(out), np.asarray(x.reshape(6, 4, 5) * (scale[0] + jnp.arange(6.0))[:, None, None]))


def test_warp_frame_loop_runs_one_flat_batch_under_nested_vmap():
    """An experiment vmaps pairs × envs. MJX flattens such a batch for Warp inside each
    ``mj_step``, and XLA then copied every data field into and out of the FFI call each frame
    (about 900 copies per Hopper env step, ``benchmarks/NOTES.md``); our step flattens once,
    so its frame loop carries the flat batch."""
    env = make_env("hopper", physics="warp", max_batch=6)
    keys = jax.random.split(jax.random.key(0), 6).reshape(2, 3)
    states = jax.vmap(jax.vmap(env.reset))(keys)
    jaxpr = jax.make_jaxpr(jax.vmap(jax.vmap(env.step)))(states, jnp.zeros((2, 3, env.action_size)))
    frame_loops = [eqn for eqn in _equations(jaxpr.jaxpr) if eqn.primitive.name in ("scan", "while")
                   and any(inner.primitive.name == "ffi_call" for inner in _equations(eqn))]
    assert frame_loops, "no loop around Warp's FFI step"
    for loop in frame_loops:
        batch_shapes = {var.aval.shape[:2] for var in loop.outvars if len(var.aval.shape) >= 2}
        assert (2, 3) not in batch_shapes and (6,) in {shape[:1] for shape in batch_shapes}, batch_shapes


def test_jax_physics_steps_a_batch_past_worlds_per_call_in_pieces():
    """On a CPU a JAX physics call past ~256 KiB of worlds' data costs 2.5-3x as much per
    world (``EnvOptions.worlds_per_call``): pairs × envs = 2 × 3 worlds at most 4 a call are
    stepped as a loop over 2 pieces, each piece's frame loop over 3 worlds."""
    env = make_env("hopper", physics="jax", worlds_per_call=4)
    states = jax.vmap(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 6).reshape(2, 3))
    jaxpr = jax.make_jaxpr(jax.vmap(jax.vmap(env.step)))(states, jnp.zeros((2, 3, env.action_size)))
    nq = env.mj_model.nq
    piece_loops = [eqn for eqn in _equations(jaxpr.jaxpr) if eqn.primitive.name == "scan" and eqn.params["length"] == 2
                   and any(var.aval.shape == (2, 3, nq) for var in eqn.outvars)]
    assert len(piece_loops) == 1, "no loop over pieces around the physics"
    frame_loops = [eqn for eqn in _equations(piece_loops[0]) if eqn.primitive.name in ("scan", "while")
                   and any(var.aval.shape == (3, nq) for var in eqn.outvars)]
    assert frame_loops, "no frame loop over a piece of 3 worlds"


def _equations(jaxpr_or_equation):
    """Every equation inside a jaxpr or an equation (its loop bodies, calls, branches), however deep."""
    if isinstance(jaxpr_or_equation, jax.extend.core.JaxprEqn):
        inner = [param for value in jaxpr_or_equation.params.values()
                 for param in (value if isinstance(value, (list, tuple)) else (value,))]
        for jaxpr in inner:
            if isinstance(jaxpr, jax.extend.core.ClosedJaxpr):
                jaxpr = jaxpr.jaxpr
            if isinstance(jaxpr, jax.extend.core.Jaxpr):
                yield from _equations(jaxpr)
        return
    for eqn in jaxpr_or_equation.eqns:
        yield eqn
        yield from _equations(eqn)


def test_make_env_names_and_spaces(tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)  # where MuJoCo would write MUJOCO_LOG.TXT
    for name, alias, obs_size, action_size in (
        ("hopper", "Hopper-v5", 11, 3),
        ("walker2d", "Walker2d-v5", 17, 6),
        ("ant", "Ant-v5", 105, 8),
        ("halfcheetah", "HalfCheetah-v5", 17, 6),
    ):
        env = make_env(alias)
        assert env.name == name
        # On a CPU the JAX physics steps at most 256 KiB of worlds' data a call (EnvOptions.worlds_per_call).
        assert env.physics.worlds_per_call == {"hopper": 32, "walker2d": 16, "ant": 8, "halfcheetah": 16}[name]
        assert env.steps_cost_each_world  # (so an experiment scores its pairs in turn)
        assert (env.observation_size, env.action_size) == (obs_size, action_size)
        with settotalmass_warning_dropped():
            gym_env = gymnasium.make(alias)
        np.testing.assert_array_equal(np.asarray(env.action_low), gym_env.action_space.low)
        np.testing.assert_array_equal(np.asarray(env.action_high), gym_env.action_space.high)
        assert gym_env.observation_space.shape == (obs_size,)
        assert env.dt == pytest.approx(gym_env.unwrapped.dt)
        gym_env.close()
    # Gymnasium's half_cheetah.xml draws a MuJoCo deprecation warning users cannot act on:
    # none of it reaches their output or working directory.
    assert "settotalmass" not in capfd.readouterr().err and not os.listdir(tmp_path)
    with pytest.raises(ValueError, match="valid names: hopper, walker2d, ant, halfcheetah"):
        make_env("cheetah")
    # Options are one frozen bundle, checked when it is built.
    options = EnvOptions(episode_length=7, physics="jax")
    env = make_env("point_mass", options)
    assert env.max_episode_steps == 7 and env.options is options and env.steps_cost_each_world
    assert not make_env("hopper", physics="warp").steps_cost_each_world  # kernel launches: about the same for any batch
    # Keyword arguments beside the bundle override its fields (make_env's docstring).
    shorter = make_env("point_mass", options, episode_length=3)
    assert shorter.max_episode_steps == 3 and shorter.options == dataclasses.replace(options, episode_length=3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.episode_length = 8
    # The solver options reach the model the physics steps: the XML's own unless overridden.
    xml_opt = make_env("hopper", physics="jax").physics.model.opt
    faster = make_env("hopper", physics="jax", solver_iterations=2, ls_iterations=3).physics.model.opt
    assert (int(faster.iterations), int(faster.ls_iterations)) == (2, 3) != (int(xml_opt.iterations),
                                                                             int(xml_opt.ls_iterations))
    for bad, message in ((dict(episode_length=0), "episode_length"), (dict(episode_length=1001), "v5 limit"),
                         (dict(physics="cuda"), "physics must be one of"), (dict(max_batch=0), "max_batch"),
                         (dict(solver_iterations=0), "solver_iterations"),
                         (dict(deterministic="false"), "deterministic must be a bool, got 'false'"),
                         (dict(terminate_when_unhealthy=0), "terminate_when_unhealthy must be a bool, got 0"),
                         (dict(graph_mode="FAST"), "graph_mode must be None or one of WARP, WARP_STAGED, NONE, got 'FAST'"),
                         (dict(worlds_per_call=-1), r"worlds_per_call must be an int >= 0 \(0: from the world's size\), got -1"),
                         (dict(physics="warp", worlds_per_call=4), "^worlds_per_call=4 splits the JAX physics' batch; MuJoCo Warp")):
        with pytest.raises(ValueError, match=message):
            make_env("hopper", **bad)
    # A CUDA-graph mode on the CPU: refused in one line when the env is made, not at its first step.
    with pytest.raises(ValueError, match=r"^graph_mode='WARP' captures CUDA graphs, which MuJoCo Warp on the CPU has not"):
        make_env("hopper", physics="warp", graph_mode="WARP")
    with pytest.raises(TypeError):
        make_env(3)
