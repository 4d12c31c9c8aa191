"""Batched random-policy rollout: a quick check of an env's compile time and throughput.

``python -m admissable_jax.rollout env=hopper num_envs=128 steps=200`` runs ``num_envs``
environments for ``steps`` steps each under uniform random actions, with automatic resets,
as one jitted ``lax.scan``, and prints compile time and env steps per second.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp

from admissable_jax.cli import compiled_in_background, parse_args, run_from_cli, run_main
from admissable_jax.envs import MjxEnv, canonical_env_name, make_env, reset_where_done, resolve_physics


@dataclasses.dataclass
class RolloutConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d, ant or halfcheetah"})
    num_envs: int = dataclasses.field(default=64, metadata={"help": "parallel environments"})
    steps: int = dataclasses.field(default=100, metadata={"help": "steps per environment"})
    seed: int = dataclasses.field(default=0, metadata={"help": "PRNG seed"})
    physics: str = dataclasses.field(default="auto", metadata={"help": "auto | jax | warp"})


def _validate(config: RolloutConfig) -> None:
    canonical_env_name(config.env)
    resolve_physics(config.physics)
    if config.num_envs < 1 or config.steps < 1:
        raise ValueError("num_envs and steps must be >= 1")
    if config.seed < 0:  # as train's
        raise ValueError(f"seed must be >= 0, got {config.seed}")


def random_actions(env: MjxEnv, num_envs: int, rng: jax.Array) -> jax.Array:
    """``num_envs`` actions drawn uniformly from the env's action box."""
    return jax.random.uniform(rng, (num_envs, env.action_size), minval=env.action_low, maxval=env.action_high)


def random_rollout(env: MjxEnv, num_envs: int, steps: int, rng: jax.Array):
    """Final states and the summed reward of a batched random-policy rollout."""

    def step(carry, rng):
        states, total_reward = carry
        action_rng, reset_rng = jax.random.split(rng)
        states = jax.vmap(env.step)(states, random_actions(env, num_envs, action_rng))
        total_reward = total_reward + states.reward.sum()
        reset_keys = jax.random.split(reset_rng, num_envs)
        return (jax.vmap(reset_where_done, (None, 0, 0))(env, states, reset_keys), total_reward), None

    init_rng, scan_rng = jax.random.split(rng)
    states = jax.vmap(env.reset)(jax.random.split(init_rng, num_envs))
    (states, total_reward), _ = jax.lax.scan(
        step, (states, jnp.zeros(())), jax.random.split(scan_rng, steps)
    )
    return states, total_reward


def measure(config: RolloutConfig) -> str:
    """Compile and run the rollout ``config`` describes; one line saying how fast."""
    env = make_env(config.env, physics=config.physics, max_batch=config.num_envs)
    rollout = jax.jit(random_rollout, static_argnums=(0, 1, 2))
    rng = jax.random.key(config.seed)
    start = time.perf_counter()
    compiled = compiled_in_background(rollout.lower(env, config.num_envs, config.steps, rng))
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    _, total_reward = jax.block_until_ready(compiled(rng))
    run_s = time.perf_counter() - start
    env_steps = config.num_envs * config.steps
    return (f"{env.display_name} on {jax.devices()[0].platform} ({env.physics_name} physics): "
            f"{config.num_envs} envs x {config.steps} steps, compile {compile_s:.1f} s, run {run_s:.2f} s, "
            f"{env_steps / run_s:,.0f} env steps/s, mean reward {float(total_reward) / env_steps:.3f}")


def main(argv: list[str]) -> int:
    config = parse_args(
        RolloutConfig, argv, "admissable_jax.rollout", __doc__.strip().splitlines()[0], _validate
    )
    line, status = run_from_cli(measure, config, interrupted="interrupted: nothing measured")
    if not status:
        print(line)
    return status


if __name__ == "__main__":
    run_main(main)
