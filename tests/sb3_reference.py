"""Record one Stable-Baselines3 SAC gradient step, for ``tests/test_agent.py`` to compare ours against.

    python3 -m venv /tmp/sb3 && /tmp/sb3/bin/pip install torch==2.13.0 stable-baselines3==2.9.2 gymnasium==1.4.0
    /tmp/sb3/bin/python tests/sb3_reference.py   # writes tests/data/sb3_sac_step.npz

The test command does not install PyTorch (a large download for one test), so the test
reads this recorded file. Nothing here imports admissable_jax: SB3's own networks, at their
own (PyTorch ``Linear``) initialisation, take one ``SAC.train`` step on a fixed random batch.
The Gaussian noise of its two policy samples (current and next observations) is drawn here
with NumPy and fed to SB3 through ``Normal.rsample``, and recorded, so the test can give our
update the same noise. The file holds the weights before and after the step, the batch, the
noise, SB3's deterministic action and squashed-Gaussian log-probabilities, its critic target
(as handed to ``F.mse_loss``), its three losses and its entropy coefficient.
"""

from __future__ import annotations

import os

import gymnasium
import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import SAC
from stable_baselines3.sac import sac as sb3_sac

OBS_SIZE, ACTION_SIZE, HIDDEN, BATCH = 6, 2, 16, 8
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "sb3_sac_step.npz")


class ShapesOnly(gymnasium.Env):
    """Only the spaces: SB3 builds its networks from them; train() never steps the env."""

    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (OBS_SIZE,), np.float32)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (ACTION_SIZE,), np.float32)

    def reset(self, *, seed=None, options=None):
        return np.zeros(OBS_SIZE, np.float32), {}

    def step(self, action):
        return np.zeros(OBS_SIZE, np.float32), 0.0, False, False, {}


def weights(model: SAC, prefix: str) -> dict[str, np.ndarray]:
    modules = {"actor": model.actor, "critic": model.critic, "critic_target": model.critic_target}
    arrays = {}
    for name, module in modules.items():
        for key, tensor in module.state_dict().items():
            arrays[f"{prefix}/{name}/{key}"] = tensor.detach().cpu().numpy().copy()
    arrays[f"{prefix}/log_ent_coef"] = model.log_ent_coef.detach().cpu().numpy().copy()
    return arrays


def main() -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = SAC("MlpPolicy", ShapesOnly(), batch_size=BATCH, learning_starts=0, seed=0,
                policy_kwargs={"net_arch": [HIDDEN, HIDDEN]})
    model.set_logger(stable_baselines3.common.logger.configure(None, []))

    batch = {
        "obs": rng.normal(size=(BATCH, OBS_SIZE)).astype(np.float32),
        "action": rng.uniform(-1, 1, size=(BATCH, ACTION_SIZE)).astype(np.float32),
        "reward": rng.normal(size=BATCH).astype(np.float32),
        "next_obs": rng.normal(size=(BATCH, OBS_SIZE)).astype(np.float32),
        "terminated": (np.arange(BATCH) % 3 == 0).astype(np.float32),
    }
    noise = {"actor_noise": rng.normal(size=(BATCH, ACTION_SIZE)).astype(np.float32),
             "next_noise": rng.normal(size=(BATCH, ACTION_SIZE)).astype(np.float32)}
    record = {**{f"batch/{k}": v for k, v in batch.items()}, **{f"noise/{k}": v for k, v in noise.items()}}
    record.update(weights(model, "before"))

    def as_torch(array):
        return torch.as_tensor(array, device=model.device)

    # SB3's policy outputs on the batch: deterministic action, and a sample with our noise.
    draws = iter([noise["actor_noise"]])
    torch.distributions.Normal.rsample = lambda self, sample_shape=torch.Size(): self.loc + self.scale * as_torch(next(draws))
    with torch.no_grad():
        record["sb3/deterministic_action"] = model.actor(as_torch(batch["obs"]), deterministic=True).cpu().numpy()
        action, log_prob = model.actor.action_log_prob(as_torch(batch["obs"]))
    record["sb3/sampled_action"], record["sb3/log_prob"] = action.cpu().numpy(), log_prob.cpu().numpy()

    # One train() step on exactly this batch and noise (current obs first, then next obs, as train() draws).
    draws = iter([noise["actor_noise"], noise["next_noise"]])
    samples = stable_baselines3.common.type_aliases.ReplayBufferSamples(
        observations=as_torch(batch["obs"]), actions=as_torch(batch["action"]),
        next_observations=as_torch(batch["next_obs"]), dones=as_torch(batch["terminated"][:, None]),
        rewards=as_torch(batch["reward"][:, None]),
    )
    model.replay_buffer.sample = lambda batch_size, env=None: samples
    targets = []
    mse_loss = sb3_sac.F.mse_loss
    sb3_sac.F.mse_loss = lambda current, target: (targets.append(target.cpu().numpy().copy()), mse_loss(current, target))[1]
    model.train(gradient_steps=1, batch_size=BATCH)
    sb3_sac.F.mse_loss = mse_loss
    record["sb3/critic_target"] = targets[0][:, 0]
    logged = model.logger.name_to_value
    for key in ("actor_loss", "critic_loss", "ent_coef_loss", "ent_coef"):
        record[f"sb3/{key}"] = np.float32(logged[f"train/{key}"])
    record.update(weights(model, "after"))
    record["versions"] = np.array(f"torch {torch.__version__}, stable-baselines3 {stable_baselines3.__version__}")

    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    np.savez_compressed(OUT, **record)
    print(f"wrote {OUT}: {len(record)} arrays ({record['versions']})")


if __name__ == "__main__":
    main()
