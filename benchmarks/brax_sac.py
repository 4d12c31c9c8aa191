"""Brax's own SAC (``brax.training.agents.sac``) on our MJX env, at settings matched to ours.

    python benchmarks/brax_sac.py env=hopper num_envs=128 steps_per_epoch=50

Our env is wrapped as a ``brax.envs.base.Env`` (same MJX physics, same XML solver
settings); Brax adds its own episode (1000-step) and auto-reset wrappers. Matched to our
trainer: ``num_envs`` envs stepped per iteration, ``num_envs · utd`` gradient steps per
iteration (UTD 1), minibatch 256, 256×256 networks, Adam 3e-4, γ = 0.99, τ = 0.005.
Brax's policy sees the d raw features where ours sees the 2·d masked vector: d·256 more
weights in each network's first layer, a few percent of an update's FLOPs (estimated).

Brax times every training epoch; the first one includes compilation, so three evaluations
are asked for and the second epoch's ``training/sps`` is reported. Appends a record to
benchmarks/results/brax_sac.jsonl.

``update_only=true`` times the SAC updates alone instead, in one process: Brax's
``sgd_step`` (entropy coefficient, critics, actor, targets, built from Brax's own losses and
networks at their defaults) and our ``SAC.update`` on the 2·d masked input and on the d raw
features, each a scan of ``updates`` (200) updates on one fixed minibatch, with XLA's FLOP
count of one update:

    python benchmarks/brax_sac.py env=hopper update_only=true
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import optax

from admissable_jax.envs import warp_package

# Before Brax imports MJX, as envs/physics.py does: MJX's Warp bridge then runs the
# mujoco-warp package, which the deterministic mode (the default) needs; after Brax, every
# Warp run here was refused with that one line.
warp_package.use_package()
from brax.envs import base as brax_base  # noqa: E402
from brax.training.agents.sac import train as brax_sac_train  # noqa: E402

from admissable_jax.cli import check_at_least_one, parse_args  # noqa: E402
from admissable_jax.envs import MjxEnv, make_env  # noqa: E402
from common import append_record, compiled_updates, peak_host_memory_mb, run_benchmark, update_flops  # noqa: E402


def _device_put_replicated(tree, devices):
    """What ``jax.device_put_replicated`` did (Brax 0.14.2 still calls it; JAX 0.10 removed
    it): a leading axis of one copy per device, the layout ``jax.pmap`` expects."""
    return jax.device_put(jax.tree.map(lambda leaf: jnp.stack([leaf] * len(devices)), tree), devices[0])


class BraxEnv(brax_base.Env):
    """One of our MJX envs behind Brax's Env interface. ``done`` is termination only: Brax's
    EpisodeWrapper adds the 1000-step truncation (and bootstraps through it, as we do)."""

    def __init__(self, env: MjxEnv):
        self.env = env  # its own 1000-step truncation flag is not read: Brax's wrapper truncates

    def reset(self, rng: jax.Array) -> brax_base.State:
        state = self.env.reset(rng)
        return brax_base.State(pipeline_state=state, obs=state.obs, reward=state.reward,
                               done=state.terminated.astype(state.reward.dtype))

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        stepped = self.env.step(state.pipeline_state, action)
        return state.replace(pipeline_state=stepped, obs=stepped.obs, reward=stepped.reward,
                             done=stepped.terminated.astype(stepped.reward.dtype))

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    @property
    def backend(self) -> str:
        return "mjx"


@dataclasses.dataclass
class BraxBenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d or ant"})
    num_envs: int = dataclasses.field(default=128, metadata={"help": "parallel envs"})
    utd: float = dataclasses.field(default=1.0, metadata={"help": "gradient steps per env step"})
    batch_size: int = dataclasses.field(default=256, metadata={"help": "SAC minibatch"})
    steps_per_epoch: int = dataclasses.field(default=50, metadata={"help": "training iterations per timed epoch"})
    num_eval_envs: int = dataclasses.field(default=8, metadata={"help": "Brax's evaluation envs (outside the timing)"})
    update_only: bool = dataclasses.field(default=False, metadata={"help": "time Brax's SAC update alone against ours"})
    updates: int = dataclasses.field(default=200, metadata={"help": "update_only: updates per timed scan"})
    rounds: int = dataclasses.field(default=4, metadata={"help": "update_only: timed rounds, each update's best kept"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp (the env's physics backend)"})
    episode_length: int = dataclasses.field(default=1000, metadata={"help": "Brax's episode length (truncation and evaluation; v5: 1000, shorter only for smoke runs)"})


def _validate(bench: BraxBenchConfig) -> None:
    check_at_least_one(bench, ("num_envs", "batch_size", "steps_per_epoch", "num_eval_envs", "episode_length",
                               "updates", "rounds"))
    if bench.utd <= 0:
        raise ValueError(f"utd must be > 0, got {bench.utd}")
    if len(jax.local_devices()) != 1:
        raise ValueError("run on one device (Brax would pmap over all of them; ours uses one)")


def _brax_update(obs_size: int, action_size: int):
    """(initial state, update(state, transitions, key)) of Brax's SAC gradient step."""
    from brax.training import gradients
    from brax.training.acme import running_statistics, specs
    from brax.training.agents.sac import losses as sac_losses
    from brax.training.agents.sac import networks as sac_networks

    network = sac_networks.make_sac_networks(obs_size, action_size)
    alpha_loss, critic_loss, actor_loss = sac_losses.make_losses(network, reward_scaling=1.0, discounting=0.99, action_size=action_size)
    optimizer = optax.adam(3e-4)
    alpha_update, critic_update, actor_update = (
        gradients.gradient_update_fn(loss, optimizer, pmap_axis_name=None) for loss in (alpha_loss, critic_loss, actor_loss)
    )
    policy_params = network.policy_network.init(jax.random.key(0))
    q_params = network.q_network.init(jax.random.key(1))
    log_alpha = jnp.zeros(())
    state = {
        "policy": policy_params, "q": q_params, "target_q": q_params, "log_alpha": log_alpha,
        "policy_opt": optimizer.init(policy_params), "q_opt": optimizer.init(q_params), "alpha_opt": optimizer.init(log_alpha),
        "normalizer": running_statistics.init_state(specs.Array((obs_size,), jnp.dtype("float32"))),
    }

    def update(state, transitions, key):  # brax/training/agents/sac/train.py: sgd_step
        key_alpha, key_critic, key_actor = jax.random.split(key, 3)
        _, log_alpha, alpha_opt = alpha_update(state["log_alpha"], state["policy"], state["normalizer"], transitions, key_alpha, optimizer_state=state["alpha_opt"])
        alpha = jnp.exp(state["log_alpha"])
        _, q_params, q_opt = critic_update(state["q"], state["policy"], state["normalizer"], state["target_q"], alpha, transitions, key_critic, optimizer_state=state["q_opt"])
        _, policy_params, policy_opt = actor_update(state["policy"], state["normalizer"], q_params, alpha, transitions, key_actor, optimizer_state=state["policy_opt"])
        target_q = jax.tree.map(lambda target, new: target * (1 - 0.005) + new * 0.005, state["target_q"], q_params)
        return {**state, "policy": policy_params, "q": q_params, "target_q": target_q, "log_alpha": log_alpha,
                "policy_opt": policy_opt, "q_opt": q_opt, "alpha_opt": alpha_opt}

    return state, update


def compare_updates(bench: BraxBenchConfig) -> None:
    """Brax's SAC update and ours (on the 2·d masked input, and on the d raw features as
    Brax sees them), alone, on random minibatches of the same size. The three are timed in
    turn, ``bench.rounds`` times, and each keeps its best round, so drifts of the machine's
    speed hit all three alike."""
    from brax.training.types import Transition

    from admissable_jax.agent import SAC, SACBatch, SACHyperparams

    env = make_env(bench.env)
    d, a, b, updates, rounds = env.observation_size, env.action_size, bench.batch_size, bench.updates, bench.rounds
    keys = jax.random.split(jax.random.key(3), 4)
    obs, next_obs = jax.random.normal(keys[0], (b, 2 * d)), jax.random.normal(keys[1], (b, 2 * d))
    action = jax.random.uniform(keys[2], (b, a), minval=-1, maxval=1)
    reward = jax.random.normal(keys[3], (b,))
    brax_state, brax_update = _brax_update(d, a)
    transitions = Transition(observation=obs[:, :d], action=action, reward=reward, discount=jnp.ones(b),
                             next_observation=next_obs[:, :d], extras={"state_extras": {"truncation": jnp.zeros(b)}, "policy_extras": {}})
    runners = {"brax": (update_flops(brax_update, brax_state, transitions),
                        compiled_updates(brax_update, brax_state, transitions, updates))}
    for name, width in (("ours", 2 * d), ("ours_raw_input", d)):
        agent = SAC(width, env.action_low, env.action_high, SACHyperparams(batch_size=b))
        batch = SACBatch(obs=obs[:, :width], action=action, reward=reward, next_obs=next_obs[:, :width], terminated=jnp.zeros(b, bool))
        update, state = (lambda s, bt, k, agent=agent: agent.update(s, bt, k)[0]), agent.init(jax.random.key(4))
        runners[name] = (update_flops(update, state, batch), compiled_updates(update, state, batch, updates))
    best = dict.fromkeys(runners, float("inf"))
    for _ in range(rounds):
        for name, (_, run) in runners.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    rates = {name: {"updates_per_s": round(updates / best[name], 1), "update_gflop": round(runners[name][0] / 1e9, 4)} for name in runners}
    record = {"env": env.gymnasium_id, "mode": "update_only", "batch_size": b, "inputs": {"brax": d, "ours": 2 * d, "ours_raw_input": d},
              **rates, "ours_over_brax": round(rates["ours"]["updates_per_s"] / rates["brax"]["updates_per_s"], 3),
              "ours_raw_input_over_brax": round(rates["ours_raw_input"]["updates_per_s"] / rates["brax"]["updates_per_s"], 3)}
    print(f"{env.gymnasium_id}, batch {b}, best of {rounds} rounds of {updates} updates each:")
    for name, rate in rates.items():
        print(f"  {name:15s} input {record['inputs'][name]:4d}: {rate['updates_per_s']:8,.1f} updates/s, {rate['update_gflop']} GFLOP")
    print(f"ours / Brax = {record['ours_over_brax']:.2f}; on Brax's input width = {record['ours_raw_input_over_brax']:.2f}")
    append_record("brax_sac", record)


def main(argv: list[str]) -> None:
    bench = parse_args(BraxBenchConfig, argv, "benchmarks/brax_sac.py", __doc__.splitlines()[0], _validate)
    if bench.update_only:
        return compare_updates(bench)
    jax.device_put_replicated = _device_put_replicated
    env = BraxEnv(make_env(bench.env, physics=bench.physics, max_batch=max(bench.num_envs, bench.num_eval_envs)))
    grad_updates = max(1, round(bench.num_envs * bench.utd))
    min_replay = max(bench.batch_size, bench.num_envs) * 4
    # Brax: num_timesteps covers the prefill plus (num_evals - 1) epochs.
    epoch_env_steps = bench.steps_per_epoch * bench.num_envs
    num_timesteps = min_replay + 2 * epoch_env_steps
    progress: list[tuple[int, dict]] = []
    started = time.perf_counter()
    brax_sac_train.train(
        environment=env, num_timesteps=num_timesteps, episode_length=bench.episode_length, num_envs=bench.num_envs,
        num_eval_envs=bench.num_eval_envs, learning_rate=3e-4, discounting=0.99, batch_size=bench.batch_size,
        num_evals=3, min_replay_size=min_replay, max_replay_size=1_000_000, grad_updates_per_step=grad_updates,
        tau=0.005, seed=0, progress_fn=lambda step, metrics: progress.append((step, dict(metrics))),
    )
    total_s = time.perf_counter() - started
    timed = [metrics for _, metrics in progress if "training/sps" in metrics]
    if len(timed) < 2:
        raise ValueError(f"Brax reported {len(timed)} timed epochs; need 2 (raise steps_per_epoch)")
    env_sps = float(timed[1]["training/sps"])
    record = {
        "env": env.env.gymnasium_id, "physics": env.env.physics_name, "trainer": "brax.training.agents.sac", "num_envs": bench.num_envs,
        "utd": bench.utd, "grad_updates_per_iteration": grad_updates, "batch_size": bench.batch_size,
        "hidden_sizes": [256, 256], "steps_per_epoch": bench.steps_per_epoch,
        "env_steps_per_s": round(env_sps, 1), "grad_steps_per_s": round(env_sps * grad_updates / bench.num_envs, 1),
        "first_epoch_sps_with_compile": round(float(timed[0]["training/sps"]), 1),
        "total_s_with_compile_and_evals": round(total_s, 1), "peak_host_memory_mb": round(peak_host_memory_mb(), 1),
    }
    print(f"Brax SAC, {record['env']}: {bench.num_envs} envs, {grad_updates} gradient steps per iteration: "
          f"{env_sps:,.1f} env steps/s (second epoch; whole run {total_s:.0f} s with compile and evals)")
    append_record("brax_sac", record)


if __name__ == "__main__":
    run_benchmark(main)
