"""The paper's method in any Gymnasium pipeline: masked observations, the adversary, and a_u
for any Python policy. NumPy and Gymnasium only: nothing here imports JAX.

- :class:`MissingnessObservation` hides a set u of observation features (zeroed) and
  appends the 0/1 indicator of u (2·d features), for a fixed u or one chosen per episode,
  from the episode's start (the paper) or from the env step its sensors fail (``fail_at``).
- :class:`AdversarialMissingness` draws u ~ p_miss at every reset (fixed for the episode)
  and applies the paper's p_miss update in :meth:`~AdversarialMissingness.update`.
- :func:`score_policy` computes every a_u (and the clean return) for any policy on
  Gymnasium's vector envs: the numbers the adversary's update takes.

Stable-Baselines3, CleanRL or hand-written PyTorch train on the wrapped env as on any
other; the README shows SB3's SAC with a callback that scores every ζ steps.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Iterable, Sequence

import gymnasium
import numpy as np
from tqdm.auto import tqdm

from admissable_jax.method import DRAWING_MODES, candidate_sets, fail_steps, hidden_from_step, hidden_row, \
    inverse_score_p_miss, mask_observation, spread_fail_steps, worst_set_p_miss

HiddenChoice = Callable[[np.random.Generator], Iterable[int]]


class MissingnessObservation(gymnasium.ObservationWrapper, gymnasium.utils.RecordConstructorArgs):
    """The paper's masked observation m_u(s) ⊕ 1[u] of a flat Box observation (2·d features).

    ``hidden`` is the set u of feature indices to hide in every episode (``()``: none), or a
    function ``choose(rng) -> indices`` called at every reset with this wrapper's own NumPy
    generator (seeded by ``reset(seed=...)``), for one u per episode. The current u is
    :attr:`hidden_row`, and ``info["hidden"]`` at reset lists its indices.

    ``fail_at``: the env step of each episode at which u's sensors fail, every feature seen
    (and the indicator 0) until then; 0, the paper's, hides u from the start. A sequence of
    steps draws one per episode, uniformly, with the same generator (``info["fail_at"]`` at
    reset, :attr:`fail_at`), as ``train fail_at=0,50,100`` does.
    """

    def __init__(self, env: gymnasium.Env, hidden: Iterable[int] | HiddenChoice = (),
                 fail_at: int | Sequence[int] = 0):
        gymnasium.utils.RecordConstructorArgs.__init__(self, hidden=hidden, fail_at=fail_at)  # for env specs (check_env)
        super().__init__(env)
        self.fail_steps = fail_steps(fail_at, getattr(env.spec, "max_episode_steps", None))
        self.fail_at = self.fail_steps[0]  # this episode's
        self._steps_taken = 0
        space = env.observation_space
        if not isinstance(space, gymnasium.spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"MissingnessObservation needs a flat Box observation space, got {space}")
        self.num_features = int(space.shape[0])
        self._choose = hidden if callable(hidden) else None
        self.hidden_row = np.zeros(self.num_features, np.float32) if callable(hidden) else hidden_row(hidden, self.num_features)
        self._rng = np.random.default_rng()
        zeros, ones = np.zeros(self.num_features, space.dtype), np.ones(self.num_features, space.dtype)
        self.observation_space = gymnasium.spaces.Box(
            low=np.concatenate([np.minimum(space.low, 0), zeros]),
            high=np.concatenate([np.maximum(space.high, 0), ones]),
            dtype=space.dtype,
        )

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._rng = np.random.default_rng([seed, 0x6D61736B])  # apart from the env's own stream
        if self._choose is not None:
            self.hidden_row = hidden_row(self._choose(self._rng), self.num_features)
        if len(self.fail_steps) > 1:
            self.fail_at = int(self._rng.choice(self.fail_steps))
        self._steps_taken = 0
        obs, info = self.env.reset(seed=seed, options=options)
        return self.observation(obs), {**info, "hidden": np.flatnonzero(self.hidden_row).tolist(), "fail_at": self.fail_at}

    def step(self, action):
        self._steps_taken += 1
        return super().step(action)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        hidden = hidden_from_step(self.hidden_row[None], np.asarray([self._steps_taken]), self.fail_at)[0]
        return mask_observation(np.asarray(observation, self.observation_space.dtype), hidden)


class AdversarialMissingness(MissingnessObservation):
    """u ~ p_miss over all sets of ``k`` features (of 1 to ``k`` with ``up_to_k``, the
    paper's |u| <= k), drawn at every reset and fixed for the episode (paper §3).
    ``update(scores)`` takes a_u for every set, in the order of :attr:`candidate_sets`
    (what :func:`score_policy` returns, given the same ``k`` and ``up_to_k``), and sets
    p_miss(u) ∝ 1/(max(a_u, l) − l + ε) in ``mode="adversarial"``; ``"uniform"`` keeps p_miss
    uniform (the paper's baseline); ``"worst"`` puts it all on argmin_u a_u (the deterministic
    adversary the paper decides against, ties shared). In a vector env every copy holds its own p_miss:
    ``envs.call("update", scores)`` updates them all. ``fail_at`` as in
    :class:`MissingnessObservation`.
    """

    def __init__(self, env: gymnasium.Env, k: int = 1, mode: str = "adversarial", lower_bound: float = 0.0,
                 epsilon: float = 1e-8, include_empty_set: bool = False, seed: int | None = None,
                 up_to_k: bool = False, fail_at: int | Sequence[int] = 0):
        if mode not in DRAWING_MODES:
            raise ValueError(f"mode must be one of {', '.join(DRAWING_MODES)}, got {mode!r}")
        if not np.isfinite(lower_bound):
            raise ValueError(f"lower_bound must be a finite number, got {lower_bound}")
        if not 0 < epsilon < np.inf:
            raise ValueError(f"epsilon must be > 0 and finite, got {epsilon}")
        gymnasium.utils.RecordConstructorArgs.__init__(self, k=k, mode=mode, lower_bound=lower_bound, epsilon=epsilon,
                                                        include_empty_set=include_empty_set, seed=seed,
                                                        up_to_k=up_to_k, fail_at=fail_at)
        super().__init__(env, hidden=self._draw, fail_at=fail_at)
        self.candidate_sets = candidate_sets(self.num_features, k, include_empty_set, up_to_k)
        self.mode, self.lower_bound, self.epsilon = mode, float(lower_bound), float(epsilon)
        self.p_miss = np.full(len(self.candidate_sets), 1.0 / len(self.candidate_sets))
        self.set_index = 0
        self._rng = np.random.default_rng(seed)

    def _draw(self, rng: np.random.Generator) -> list[int]:
        self.set_index = int(rng.choice(len(self.p_miss), p=self.p_miss))
        return np.flatnonzero(self.candidate_sets[self.set_index]).tolist()

    def update(self, scores) -> np.ndarray:
        """The mode's update from a_u of every candidate set (the paper's, in mode
        ``adversarial``); returns the new p_miss."""
        scores = np.asarray(scores, np.float64)
        if scores.shape != self.p_miss.shape:
            raise ValueError(f"update needs one score per candidate set ({len(self.p_miss)}), got shape {scores.shape}")
        if not np.isfinite(scores).all():
            raise ValueError("update needs finite scores")
        if self.mode == "adversarial":
            self.p_miss = inverse_score_p_miss(scores, self.lower_bound, self.epsilon)
        elif self.mode == "worst":
            self.p_miss = worst_set_p_miss(scores)
        return self.p_miss


@dataclasses.dataclass
class PolicyScores:
    """:func:`score_policy`'s result, with :class:`~admissable_jax.scoring.MissingnessScores`'s fields, in NumPy."""

    scores: np.ndarray  # (|U|,) a_u: mean return with u hidden
    clean_score: float  # mean return with nothing hidden
    returns: np.ndarray  # (|U| + 1, N) per-episode returns; the last row is the clean case
    lengths: np.ndarray  # (|U| + 1, N) episode lengths
    loop_steps: int  # vector-env steps the rollout took
    capacity_exceeded: bool = False  # always False: C MuJoCo has no fixed-size buffers
    hidden_sets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0), np.float32))  # U, (|U|, d)


def _batch_of_actions(returned: Any, action_space: gymnasium.Space) -> np.ndarray:
    """A policy's batch of actions for a vector env (a returned tuple's first item: SB3's
    ``(actions, state)``); ValueError in one line for a batch not of the vector env's action
    shape, which Gymnasium would take apart env by env (a wider action silently cut to the
    env's first entries) or fail on deep inside its step."""
    actions = np.asarray(returned[0] if isinstance(returned, tuple) else returned)
    if actions.dtype == object or actions.shape != action_space.shape:
        got = f"shape {actions.shape}" if actions.dtype != object else repr(returned)[:80]
        raise ValueError(f"policy must return a batch of actions of shape {action_space.shape} (one per env), got {got}")
    return actions


def score_policy(env_id: str, policy: Callable[[np.ndarray], Any], k: int = 1, n_episodes: int = 10,
                 num_envs: int = 8, include_empty_set: bool = False, seed: int = 0,
                 vectorization_mode: str = "sync", hidden_sets: np.ndarray | None = None,
                 progress: bool = False, up_to_k: bool = False, fail_at: int | str | Iterable[int] = 0,
                 **env_kwargs) -> PolicyScores:
    """a_u for every set u of ``k`` features (of 1 to ``k`` with ``up_to_k``; paper §3): the
    mean undiscounted return of ``n_episodes`` episodes with u hidden, and the clean return,
    for any Python policy.
    ``hidden_sets`` ((|U|, d) 0/1 rows) scores those sets instead, in one rollout (the
    audit's sets of several sizes).

    ``policy(masked_obs) -> actions`` maps a (num_envs, 2·d) batch of masked observations to
    a batch of actions: NumPy, PyTorch behind ``.numpy()``, or SB3's
    ``lambda obs: model.predict(obs, deterministic=True)[0]`` (a returned tuple's first
    item is taken). The (|U| + 1)·N episodes run on ``num_envs`` copies of
    ``gymnasium.make_vec(env_id, ...)``, each slot starting the next unscored episode as its
    own ends; episode starts follow the vector env's seed. ``progress`` draws a bar over the
    episodes on stderr. ``fail_at``: the env step of each episode at which u's sensors fail,
    seen until then (0, the paper's a_u: hidden from the start); several steps split each
    set's N episodes evenly over them, as :func:`~admissable_jax.score_missingness` does
    (episode i at the (i mod m)-th of the m steps; N a multiple of m).
    """
    if n_episodes < 1 or num_envs < 1:
        raise ValueError("n_episodes and num_envs must be >= 1")
    spread_fail_steps(fail_at, n_episodes)  # checked before the envs are made
    envs = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode=vectorization_mode, **env_kwargs)
    try:
        episode_fail_steps = np.asarray(spread_fail_steps(
            fail_at, n_episodes, env_kwargs.get("max_episode_steps", getattr(envs.spec, "max_episode_steps", None))))
        num_features = int(envs.single_observation_space.shape[0])
        if hidden_sets is None:
            hidden_sets = candidate_sets(num_features, k, include_empty_set, up_to_k)
        hidden_sets = np.asarray(hidden_sets, np.float32)
        if hidden_sets.ndim != 2 or hidden_sets.shape[1] != num_features:
            raise ValueError(f"hidden_sets must be (sets, {num_features}) 0/1 rows for {env_id}, "
                             f"got shape {hidden_sets.shape}")
        rows = np.concatenate([hidden_sets, np.zeros((1, num_features), np.float32)])
        returns = np.zeros((len(rows), n_episodes))
        lengths = np.zeros((len(rows), n_episodes), np.int64)
        episode_of_slot = np.arange(num_envs)  # episode e: row e // N, repetition e % N
        next_episode, total = num_envs, len(rows) * n_episodes
        running_return, running_length = np.zeros(num_envs), np.zeros(num_envs, np.int64)
        resetting = np.zeros(num_envs, bool)  # next step is the vector env's autoreset of this slot
        obs, _ = envs.reset(seed=seed)
        loop_steps = 0
        with tqdm(total=total, unit="episode", disable=not progress, smoothing=0) as bar:  # closed before any error line
            while (episode_of_slot < total).any():
                row_of_slot, repetition_of_slot = np.divmod(np.minimum(episode_of_slot, total - 1), n_episodes)
                hidden = hidden_from_step(rows[row_of_slot], running_length, episode_fail_steps[repetition_of_slot])
                masked = mask_observation(np.asarray(obs, np.float32), hidden)
                actions = _batch_of_actions(policy(masked), envs.action_space)
                obs, reward, terminated, truncated, _ = envs.step(actions)
                loop_steps += 1
                counted = ~resetting & (episode_of_slot < total)
                running_return[counted] += reward[counted]
                running_length[counted] += 1
                ended = counted & (terminated | truncated)
                for slot in np.flatnonzero(ended):
                    row, repetition = divmod(int(episode_of_slot[slot]), n_episodes)
                    returns[row, repetition], lengths[row, repetition] = running_return[slot], running_length[slot]
                    episode_of_slot[slot], next_episode = next_episode, next_episode + 1
                running_return[ended], running_length[ended] = 0.0, 0
                resetting = terminated | truncated
                bar.update(int(ended.sum()))
    finally:
        envs.close()
    means = returns.mean(axis=1)
    return PolicyScores(scores=means[:-1], clean_score=float(means[-1]), returns=returns, lengths=lengths,
                        loop_steps=loop_steps, hidden_sets=hidden_sets)
