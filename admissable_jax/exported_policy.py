"""A trained policy as one NumPy file, run without JAX: :class:`ExportedPolicy`.

The trainer's deterministic policy (what scoring evaluates) is a ReLU MLP on the masked
observation m_u(s) ⊕ 1[u] (2·d inputs, paper §3) whose mean head is squashed by tanh and
scaled into the env's action bounds (``agent.SAC.deterministic_action``). ``python -m
admissable_jax.export RUN`` (``TrainedPolicy.exported()`` from Python) writes those layers,
the bounds, the feature names and where the policy came from into one ``.npz``;
:meth:`ExportedPolicy.load` reads it back and acts with NumPy alone (nothing here imports
JAX), for code that has no JAX: a robot's computer, a PyTorch pipeline, Gymnasium
evaluation (``wrappers.score_policy(env_id, policy.masked)``).

The file, as ``numpy.load`` shows it: ``format`` (:data:`FORMAT`); ``weight_<i>`` (in, out)
and ``bias_<i>`` (out) for layers i = 0..L, ReLU after each but the last, which is the mean
head (a PyTorch ``nn.Linear`` takes ``weight_<i>.T`` and ``bias_<i>``); ``action_low`` and
``action_high``; ``observation_names`` (the d features); ``source``, a JSON object: the run,
env, Gymnasium id, mode, seed, k, env step and, for a run's best policy, its min_u a_u.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zipfile
from typing import Any, Iterable

import numpy as np

from admissable_jax.errors import RunFailed, write_whole
from admissable_jax.method import act_with_hidden, check_masked_batch

FORMAT = "admissable_jax exported policy 1"


@dataclasses.dataclass(frozen=True, repr=False, eq=False)  # arrays: no elementwise == of two policies
class ExportedPolicy:
    """A deterministic policy of masked observations in NumPy.

    ``policy(obs, hidden=())`` takes a Gymnasium observation (d,) or a batch (n, d) and u as
    feature indices (or a 0/1 row) and returns the action(s); ``policy.masked(batch)`` takes
    observations already masked (n, 2·d), as :func:`~admissable_jax.wrappers.score_policy`
    and :class:`~admissable_jax.wrappers.MissingnessObservation` hand them.
    """

    weights: tuple[np.ndarray, ...]  # (in, out) per layer; the last is the mean head
    biases: tuple[np.ndarray, ...]
    action_low: np.ndarray
    action_high: np.ndarray
    observation_names: tuple[str, ...]
    # where it came from: run, env, gymnasium_id, missingness, seed, k, env_steps, ...; fail_at and score_fail_at where not 0
    source: dict[str, Any]

    def __post_init__(self):
        inputs = [weight.shape[0] for weight in self.weights]
        outputs = [weight.shape[1] for weight in self.weights]
        if (not self.weights or inputs[0] != 2 * self.observation_size or inputs[1:] != outputs[:-1]
                or [bias.shape for bias in self.biases] != [(size,) for size in outputs]
                or self.action_low.shape != (outputs[-1],) or self.action_high.shape != (outputs[-1],)):
            raise ValueError(f"layers {[weight.shape for weight in self.weights]} do not make a policy of "
                             f"2·{self.observation_size} inputs and {self.action_low.shape} actions")

    @property
    def observation_size(self) -> int:
        return len(self.observation_names)

    @property
    def action_size(self) -> int:
        return self.weights[-1].shape[1]

    def __repr__(self) -> str:
        source = self.source
        best = source.get("best_min_score")
        kept = "" if best is None else f", its best scoring (min_u a_u {best:.1f})"
        return (f"<ExportedPolicy of {source.get('env')} {source.get('missingness')} seed {source.get('seed')} at env "
                f"step {source.get('env_steps')}{kept} ({source.get('run')}): {self.observation_size} features in, "
                f"{self.action_size} actions out>")

    def masked(self, masked_obs: np.ndarray) -> np.ndarray:
        """Actions (n, A) for masked observations (n, 2·d), in float32 as the trainer computes them."""
        check_masked_batch(masked_obs, self.observation_size)
        x = np.asarray(masked_obs, np.float32)
        for weight, bias in zip(self.weights[:-1], self.biases[:-1]):
            x = np.maximum(x @ weight + bias, 0.0)
        squashed = np.tanh(x @ self.weights[-1] + self.biases[-1])
        return self.action_low + (squashed + 1.0) * 0.5 * (self.action_high - self.action_low)

    def __call__(self, obs: np.ndarray, hidden: Iterable[int] | np.ndarray = ()) -> np.ndarray:
        return act_with_hidden(self.masked, obs, hidden, self.observation_size)

    def save(self, path: str) -> None:
        """Write the policy to ``path`` (an ``.npz``), whole or not at all: a write that fails
        (a full disk, no permission) removes what it wrote and says so in one line
        (:class:`ExportNotWritten`)."""
        arrays = {f"{kind}_{layer}": array for layer, pair in enumerate(zip(self.weights, self.biases))
                  for kind, array in zip(("weight", "bias"), pair)}
        try:
            write_whole(path, lambda file: np.savez(
                file, format=np.str_(FORMAT), action_low=self.action_low, action_high=self.action_high,
                observation_names=np.array(self.observation_names, dtype=np.str_),
                source=np.str_(json.dumps(self.source)), **arrays))
        except OSError as error:
            raise ExportNotWritten(f"cannot write the exported policy {path}: {error.strerror or error}") from None

    @classmethod
    def load(cls, path: str) -> ExportedPolicy:
        """The policy in ``path``; FileNotFoundError, or ValueError in one line for a file that
        is no exported policy (another ``.npz``, a file cut short)."""
        if not os.path.isfile(path):
            raise FileNotFoundError(f"no exported policy at {path}")
        refused = ValueError(f"{path} is no exported policy of admissable_jax (python -m admissable_jax.export "
                             "writes them)")
        try:
            data = np.load(path)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # not NumPy's, or cut short
            raise refused from None
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise refused
        with data:
            try:
                found = str(data["format"])
                if found != FORMAT:
                    ours = found.startswith(FORMAT.rsplit(" ", 1)[0])  # a later (or earlier) version's layout
                    raise refused if not ours else ValueError(
                        f"{path} is an exported policy of another version of admissable_jax ({found!r}; this one "
                        f"reads {FORMAT!r})")
                layers = sum(name.startswith("weight_") for name in data.files)
                return cls(tuple(data[f"weight_{layer}"].astype(np.float32) for layer in range(layers)),
                           tuple(data[f"bias_{layer}"].astype(np.float32) for layer in range(layers)),
                           data["action_low"].astype(np.float32), data["action_high"].astype(np.float32),
                           tuple(str(name) for name in data["observation_names"]), json.loads(str(data["source"])))
            except (KeyError, OSError, zipfile.BadZipFile, json.JSONDecodeError):
                raise refused from None


class ExportNotWritten(RunFailed):
    """An exported policy could not be written (a full disk, no permission)."""
