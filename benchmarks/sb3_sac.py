"""Stable-Baselines3's SAC (the paper's own trainer) on Gymnasium's C-MuJoCo env: its
training throughput on this machine, for the "≥ 1.2× SB3" target, and with ``eval_every``
its learning curve, to set beside ours (``clean_score`` in a run's scores.jsonl).

    pip install torch stable-baselines3   # not project dependencies; CPU wheels suffice
    python benchmarks/sb3_sac.py env=hopper learning_steps=1000
    python benchmarks/sb3_sac.py env=halfcheetah learning_starts=10000 learning_steps=20000 eval_every=5000

SB3's defaults are the paper's settings: one env, UTD 1 (train_freq 1, gradient_steps 1),
batch 256, 256×256 networks, Adam 3e-4. Its networks read the d raw features (ours read the
2·d masked vector). ``learning_starts`` steps of random actions come first and are not
timed; then ``learning_steps`` steps, each one env step and one gradient step, are timed.
With ``eval_every`` the timed span also holds the evaluations: every ``eval_every`` env steps
the mean undiscounted return of ``eval_episodes`` deterministic episodes on a second env (as
SB3's ``evaluate_policy``). Appends a record to benchmarks/results/sb3_sac.jsonl.
"""

from __future__ import annotations

import dataclasses
import time

from admissable_jax.cli import parse_args
from admissable_jax.envs import make_env
from common import append_record, peak_host_memory_mb, run_benchmark


@dataclasses.dataclass
class SB3BenchConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d, ant or halfcheetah"})
    learning_starts: int = dataclasses.field(default=1000, metadata={"help": "random-action steps before learning (not timed)"})
    learning_steps: int = dataclasses.field(default=1000, metadata={"help": "timed steps, one gradient step each"})
    threads: int = dataclasses.field(default=0, metadata={"help": "torch threads (0 = torch's default)"})
    seed: int = dataclasses.field(default=0, metadata={"help": "SB3's seed"})
    eval_every: int = dataclasses.field(default=0, metadata={"help": "env steps between evaluations (0 = none)"})
    eval_episodes: int = dataclasses.field(default=5, metadata={"help": "deterministic episodes per evaluation"})


def main(argv: list[str]) -> None:
    bench = parse_args(SB3BenchConfig, argv, "benchmarks/sb3_sac.py", __doc__.splitlines()[0])
    import gymnasium
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.evaluation import evaluate_policy

    if bench.threads:
        torch.set_num_threads(bench.threads)
    env_id = make_env(bench.env).gymnasium_id
    stamps: dict[str, float] = {}
    evaluations: list[dict[str, float]] = []
    eval_env = gymnasium.make(env_id) if bench.eval_every else None

    class Stamp(BaseCallback):
        """Wall time when learning starts and when the run ends; the evaluations."""

        def _on_step(self) -> bool:
            if self.num_timesteps == bench.learning_starts + 1:
                stamps["start"] = time.perf_counter()
            if bench.eval_every and self.num_timesteps % bench.eval_every == 0:
                mean, std = evaluate_policy(self.model, eval_env, n_eval_episodes=bench.eval_episodes, deterministic=True)
                evaluations.append({"env_steps": self.num_timesteps, "clean_return": round(float(mean), 1),
                                    "std": round(float(std), 1)})
                print(f"{self.num_timesteps} env steps: clean return {mean:.1f} ± {std:.1f} (sd over "
                      f"{bench.eval_episodes} deterministic episodes)", flush=True)
            return True

        def _on_training_end(self) -> None:
            stamps["end"] = time.perf_counter()

    model = stable_baselines3.SAC("MlpPolicy", gymnasium.make(env_id), learning_starts=bench.learning_starts,
                                  seed=bench.seed, device="cpu")
    model.learn(total_timesteps=bench.learning_starts + bench.learning_steps, callback=Stamp())
    steps = bench.learning_steps - 1  # timed from the end of step learning_starts + 1
    seconds = stamps["end"] - stamps["start"]
    record = {
        "env": env_id, "trainer": f"stable_baselines3 {stable_baselines3.__version__} SAC, torch {torch.__version__}",
        "torch_threads": torch.get_num_threads(), "learning_starts": bench.learning_starts,
        "timed_steps": steps, "run_s": round(seconds, 2), "env_steps_per_s": round(steps / seconds, 1),
        "peak_host_memory_mb": round(peak_host_memory_mb(), 1), "seed": bench.seed,
    }
    if evaluations:
        record.update(eval_episodes=bench.eval_episodes, evaluations=evaluations)
    print(f"SB3 SAC, {env_id}: {record['env_steps_per_s']:,.1f} env steps/s = gradient steps/s "
          f"({steps} timed steps in {seconds:.1f} s, {record['torch_threads']} torch threads)")
    append_record("sb3_sac", record)


if __name__ == "__main__":
    run_benchmark(main)
