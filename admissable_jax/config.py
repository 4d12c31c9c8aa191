"""The training configuration: one typed dataclass with the paper's defaults.

The paper trains all three envs with the same settings (SB3 SAC defaults; ζ = 5000,
ε = 1e-8, l = 0, k = 1), so there are no per-env presets: ``env`` only picks the task.
"""

from __future__ import annotations

import dataclasses
import math
import os

import jax
import numpy as np

from admissable_jax.adversary import MODES
from admissable_jax.agent import SACHyperparams
from admissable_jax.cli import RUN_LOCATION, ConfigFile, check_at_least_one, setting
from admissable_jax.envs import canonical_env_name, env_physics, observation_size, short_env_name
from admissable_jax.loggers import parse_logger_names
from admissable_jax.method import check_exact_size, fail_steps, num_candidate_sets, spread_fail_steps
from admissable_jax.replay import buffer_capacity
from admissable_jax.scoring import SCORE_ESTIMATORS

SB3_SAC = SACHyperparams()
# The settings that name env steps of an episode at which u's sensors fail: training's and scoring's.
FAILURE_STEPS = ("fail_at", "score_fail_at")
# Where a command keeps the settings it ran with: a run in its folder (an experiment's pair too),
# an experiment beside its pairs' folders.
RUN_SETTINGS = "config.yaml"
EXPERIMENT_SETTINGS = "experiment.yaml"


@dataclasses.dataclass
class RunSettings:
    """The settings every run of an experiment shares: task, adversary, SAC, cadence."""

    # task and adversary (paper §3, Table of hyperparameters)
    env: str = setting("hopper", "hopper, walker2d or ant, the paper's (or Hopper-v5, Walker2d-v5, Ant-v5); "
                                 "halfcheetah (HalfCheetah-v5); point_mass: a seconds-to-compile toy for smoke runs; "
                                 "package.module:Class: an env of your own (envs.ExternalEnv)")
    k: int = setting(1, "features hidden per episode (|u| = k; 1 to k with up_to_k)")
    up_to_k: bool = setting(False, "U also holds every set of fewer than k features: the paper's U = {u : |u| <= k} "
                                   "(less the empty set); the same as false at k = 1")
    include_empty_set: bool = setting(False, "also let the adversary pick 'nothing hidden'")
    score_every: int = setting(5000, "zeta: env steps (over all envs) between scorings")
    score_episodes: int = setting(10, "N: deterministic episodes per missing set")
    score_envs: int = setting(0, "envs stepped at once in a scoring round; 0 = 32 on CPU, all (|U|+1)*N episodes on GPU")
    score_estimator: str = setting("rollout", "how a_u is scored: rollout (the paper's N whole episodes) | critic (the "
                                              "critic's discounted value of the N starts, no physics) | horizon "
                                              "(score_horizon steps, then the critic)")
    score_horizon: int = setting(100, "H, physics steps of score_estimator=horizon before the critic values the rest")
    pool_size: int = setting(0, "0: score every set of U every round (exact U); P > 0: score a pool of P sets, the "
                                "worst a beam search of width P finds (ranked by pool_ranker), refreshed every round: "
                                "for U too big to score whole (Ant: 5,460 pairs, 187,460 triples)")
    pool_ranker: str = setting("critic", "what ranks the pool search's candidates: critic | horizon | rollout")
    pool_explore: float = setting(0.1, "with pool_size > 0: share of adversarial episodes that hide a uniformly random "
                                       "set of all U instead of one drawn from the pool by p_miss")
    physics: str = setting("auto", "physics backend: auto (warp on an NVIDIA GPU with warp-lang, else jax) | jax | warp; "
                                   "envs without a MuJoCo model step in JAX")
    deterministic_physics: bool = setting(True, "warp only: MuJoCo Warp's deterministic mode (mujoco-warp package: atomic "
                                                "sums and slots in a fixed order), towards a GPU repeating a run bit for "
                                                "bit, so that a run can continue on another machine (fast_forward); "
                                                "false: the GPU's own order, maybe faster")
    worlds_per_call: int = setting(0, "jax physics: the most envs one physics call steps; a larger batch (an experiment's "
                                      "pairs x envs, a scoring round's slots) goes in pieces of at most this many, one after "
                                      "another; 0 = on a CPU the largest power of two whose envs' data fit 256 KiB (Hopper 32, "
                                      "Walker2d 16, Ant 8), else one call. benchmarks/physics_throughput.py worlds_per_call=... "
                                      "finds your CPU's")
    lower_bound: float = setting(0.0, "l: return lower bound; scores below are clipped to it")
    epsilon: float = setting(1e-8, "eps in p_miss = 1/(a_u - l + eps), normalised")
    fail_at: str = setting("0", "the env step of a training episode at which its hidden features' sensors fail, every "
                                "feature seen until then: 0 = hidden from the start (the paper); a comma list (0,50,100): "
                                "one step drawn uniformly per episode. Scoring (a_u, p_miss) hides u from the start, "
                                "unless score_fail_at says otherwise")
    score_fail_at: str = setting("0", "the env step of a scoring episode at which its hidden features' sensors fail: 0 = "
                                      "from the start (the paper's a_u); a comma list (0,50,100) splits each set's N "
                                      "episodes evenly over the steps (score_episodes a multiple of their number), so "
                                      "a_u, p_miss and min_u a_u are of sensors failing as fail_at's do. Rollouts only")
    # run
    total_steps: int = setting(1_000_000, "env steps to train, over all envs (rounded up to a multiple of score_every)")
    num_envs: int = setting(0, "parallel envs; 0 = the largest divisor of score_every up to 8 on CPU, 128 on GPU (125 for 5000)")
    episode_length: int = setting(1000, "step limit of an episode (Gymnasium v5: 1000)")
    # SAC: Stable-Baselines3's defaults, as agent.SACHyperparams holds them
    learning_rate: float = setting(SB3_SAC.learning_rate, "Adam learning rate (actor, critics, alpha)")
    gamma: float = setting(SB3_SAC.gamma, "discount")
    tau: float = setting(SB3_SAC.tau, "Polyak coefficient of the target critics")
    batch_size: int = setting(SB3_SAC.batch_size, "minibatch size")
    hidden_size: int = setting(SB3_SAC.hidden_sizes[0], "units per hidden layer")
    hidden_layers: int = setting(len(SB3_SAC.hidden_sizes), "hidden layers per network")
    buffer_size: int = setting(1_000_000, "replay capacity (transitions; rounded down to a multiple of num_envs, "
                                          "at least num_envs)")
    learning_starts: int = setting(10_000, "env steps of uniform random actions before learning (10,000: RL-Zoo's "
                                           "MuJoCo setting; SB3's library default is 100)")
    utd: float = setting(1.0, "gradient steps per env step: with n parallel envs an iteration takes n env steps, "
                              "then n * utd gradient steps")
    # output
    checkpoint_every: int = setting(10, "checkpoint every this many scorings (and at the end)")
    keep_checkpoints: int = setting(2, "the newest checkpoints kept on disk (each holds the replay buffer); more let "
                                       "audit steps= look back over training")
    resume: bool = setting(False, "continue the run in 'out' from its last checkpoint, with the settings in its "
                                  "config.yaml (an experiment's experiment.yaml); keys given override them. On the "
                                  "command line also auto: true where 'out' holds a checkpoint, else false (one "
                                  "command for a job that is started again)")
    resume_step: int = setting(-1, "with resume=true: the checkpoint (env step) to continue from; -1 = the latest")
    fast_forward: bool = setting(False, "with resume=true: re-train, without scoring, from that checkpoint (or from the "
                                        "start, where there is none) to the run's last recorded scoring, each p_miss "
                                        "read from scores.jsonl, checked bit for bit against metrics.jsonl; for runs "
                                        "whose checkpoints stayed on another machine")
    progress: bool = setting(True, "show a progress bar (where stderr is no terminal, a log file: a line per scoring)")
    logger: str = setting("none", "also log every scores/metrics row to: none | tensorboard (<run dir>/tensorboard) | "
                                     "wandb (the wandb extra; $WANDB_PROJECT, WANDB_MODE=offline) | tensorboard,wandb")
    time_limit: float = setting(0.0, "wall seconds this invocation may train (0 = no limit): it checkpoints and stops "
                                     "before a scoring interval that would overrun; resume=true continues")


@dataclasses.dataclass
class TrainConfig(RunSettings):
    """One training run: the shared settings plus its mode, seed and directory."""

    missingness: str = setting("adversarial", "adversarial (the paper's: p_miss ∝ 1/(a_u - l + eps)) | uniform (the "
                                              "paper's baseline) | none (nothing hidden: clean SAC) | worst (every "
                                              "episode hides argmin_u a_u: the deterministic adversary the paper "
                                              "decides against)")
    seed: int = setting(0, "PRNG seed")
    out: str = setting("", "run directory; '' = runs/<env>-<missingness>-s<seed>")

    @property
    def planned_steps(self) -> int:
        """The env steps a finished run has: ``total_steps`` rounded up to a multiple of ζ."""
        return -(-self.total_steps // self.score_every) * self.score_every

    @property
    def updates_per_iteration(self) -> int:
        """Gradient steps per iteration (one step of every env): num_envs · utd, at least 1."""
        return max(1, round(self.num_envs * self.utd))

    def resolved(self) -> "TrainConfig":
        """A copy with the env name and physics backend canonical, ``num_envs``,
        ``score_envs`` and ``out`` filled in, NumPy scalars as Python numbers, ``fail_at``
        and ``score_fail_at`` as their steps' sorted comma lists (``[100, 0]`` → ``"0,100"``),
        validated."""
        config = dataclasses.replace(self, **python_numbers(self), **comma_lists(self, FAILURE_STEPS))
        validate(config)
        for name in FAILURE_STEPS:
            setattr(config, name, ",".join(map(str, fail_steps(getattr(config, name)))))
        config.env = canonical_env_name(config.env)
        config.physics = env_physics(config.env, config.physics)
        check_sets(config)
        if config.score_envs == 0:
            num_sets = config.pool_size or num_candidate_sets(observation_size(config.env), config.k,
                                                              config.include_empty_set, config.up_to_k)
            config.score_envs = default_score_envs((num_sets + 1) * config.score_episodes)
        if config.num_envs == 0:
            config.num_envs = default_num_envs(config.score_every)
        if config.score_every % config.num_envs:
            raise ValueError(
                f"score_every ({config.score_every}) must be a multiple of num_envs ({config.num_envs})"
            )
        config.out = run_out(config)
        return config


def python_numbers(config) -> dict[str, int | float]:
    """The fields of ``config`` that hold NumPy scalars (a sweep's ``np.arange`` seeds or
    ``np.linspace`` bounds) as the Python numbers a config holds and saves: an int field's
    NumPy integer, a float field's NumPy integer or float. Anything else is left to
    :func:`validate`."""
    kinds = {"int": (np.integer,), "float": (np.integer, np.floating)}
    return {field.name: (int if field.type == "int" else float)(getattr(config, field.name))
            for field in dataclasses.fields(config) if isinstance(getattr(config, field.name), kinds.get(field.type, ()))}


def comma_lists(config, names: tuple[str, ...]) -> dict[str, str]:
    """The fields of ``names`` given as Python values where a config holds comma text: a
    sequence (``["adversarial", "uniform"]``, ``np.linspace(0, 100, 3)``, ``[0, 50]``) as the
    comma list the command line writes, an int (``fail_at=50``) as its digits."""
    return {name: ",".join(map(str, value)) if isinstance(value, (list, tuple, np.ndarray)) else str(value)
            for name in names if isinstance(value := getattr(config, name), (list, tuple, np.ndarray, np.integer, int))
            and not isinstance(value, bool)}


def run_out(config: TrainConfig) -> str:
    """A train run's directory: ``out``, or runs/<env>-<missingness>-s<seed>."""
    return config.out or f"runs/{short_env_name(config.env)}-{config.missingness}-s{config.seed}"


@dataclasses.dataclass
class ExperimentConfig(RunSettings):
    """An experiment: the settings every pair shares (``RunSettings``, as ``train`` takes
    them), plus which seeds and modes make the pairs and where they go."""

    seeds: int = setting(5, "seeds per mode: first_seed .. first_seed + seeds - 1")
    first_seed: int = setting(0, "the first seed")
    modes: str = setting("adversarial,uniform", "comma-separated missingness modes (adversarial, uniform, none, worst)")
    lower_bounds: str = setting("", "comma-separated values of l to sweep in one program: the adversarial seeds train "
                                    "once per value (pairs adversarial-l<l>-s<seed>); '' = lower_bound alone")
    out: str = setting("", "experiment directory; '' = runs/fig1-<env>")
    devices: int = setting(0, "devices the pairs are spread over: 0 = every device (of every process under "
                              "jax.distributed), N = the first N")
    budget_only: bool = setting(False, "print the memory budget and stop")

    def resolved(self) -> "ExperimentConfig":
        """A copy as the experiment runs and saves it: ``modes``, ``lower_bounds`` and
        ``fail_at`` given as Python values as the comma text the command line writes
        (:func:`comma_lists`), NumPy scalars as Python numbers; TypeError
        in one line for an experiment-only field of another type (the shared ones are each
        pair's, checked by :meth:`TrainConfig.resolved` in :func:`pair_configs`)."""
        config = dataclasses.replace(self, **python_numbers(self), **comma_lists(self, ("modes", "lower_bounds",
                                                                                        *FAILURE_STEPS)))
        shared = {field.name for field in dataclasses.fields(RunSettings)}
        check_field_types(config, [field for field in dataclasses.fields(config) if field.name not in shared])
        return config


def pair_configs(config: ExperimentConfig) -> list[TrainConfig]:
    """One resolved TrainConfig per pair, in the batch's order: modes outer, then (for the
    adversarial mode with ``lower_bounds``) the values of l, then seeds. A pair's folder is
    ``<mode>-s<seed>``, or ``adversarial-l<l>-s<seed>`` in a sweep of l; the other modes
    never read l, so a sweep trains them once."""
    modes = [mode.strip() for mode in config.modes.split(",") if mode.strip()]
    unknown = [mode for mode in modes if mode not in MODES]
    if not modes or unknown:
        raise ValueError(f"modes must be a comma-separated list of {', '.join(MODES)}, got {config.modes!r}")
    if len(set(modes)) != len(modes):
        raise ValueError(f"modes repeats a mode: {config.modes!r}")
    if config.seeds < 1 or config.first_seed < 0:
        raise ValueError(f"seeds must be >= 1 and first_seed >= 0, got seeds={config.seeds}, first_seed={config.first_seed}")
    swept = swept_lower_bounds(config)
    if swept and "adversarial" not in modes:
        raise ValueError(f"lower_bounds sweeps the adversarial mode's l, and modes={config.modes!r} has no adversarial")
    shared = {field.name: getattr(config, field.name) for field in dataclasses.fields(RunSettings)}
    out = experiment_out(config)
    curves = [(mode, bound) for mode in modes
              for bound in (swept if swept and mode == "adversarial" else [shared["lower_bound"]])]
    return [
        TrainConfig(**{**shared, "lower_bound": bound}, missingness=mode, seed=seed,
                    out=os.path.join(out, f"{curve_name(mode, bound, bool(swept))}-s{seed}")).resolved()
        for mode, bound in curves
        for seed in range(config.first_seed, config.first_seed + config.seeds)
    ]


def experiment_out(config: ExperimentConfig) -> str:
    """An experiment's directory: ``out``, or runs/fig1-<env>."""
    return config.out or f"runs/fig1-{short_env_name(config.env)}"


def curve_name(mode: str, lower_bound: float, swept: bool) -> str:
    """The curve a run is a seed of among runs trained together: its mode, or for an
    adversarial run where they sweep l, ``adversarial-l<l>`` (``adversarial-l50``)."""
    return f"adversarial-l{number_text(lower_bound)}" if swept and mode == "adversarial" else mode


def curve_mode(curve: str) -> str:
    """The mode of a :func:`curve_name` (``adversarial`` for ``adversarial-l50``), or of a
    curve that runs' settings name (``adversarial`` for ``adversarial, fail_at=0,50``:
    :attr:`~admissable_jax.results.Run.curve`)."""
    return curve.partition(",")[0].partition("-")[0]


def curve_names(modes_and_bounds: list[tuple[str, float]]) -> list[str]:
    """:func:`curve_name` of each (mode, l) of runs trained together, which sweep l where
    their adversarial runs differ in it."""
    swept = len({bound for mode, bound in modes_and_bounds if mode == "adversarial"}) > 1
    return [curve_name(mode, bound, swept) for mode, bound in modes_and_bounds]


def number_text(value: float) -> str:
    """A number as short text that reads back to it: ``50`` for 50.0, ``2.5``, ``1e-08``."""
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)


def swept_lower_bounds(config: ExperimentConfig) -> list[float]:
    """The values of ``lower_bounds`` (``"0,50"`` → [0.0, 50.0]); [] for ''. ValueError in one
    line for a value that is no finite number, or a repeated one."""
    texts = [text.strip() for text in str(config.lower_bounds).split(",") if text.strip()]
    try:
        bounds = [float(text) for text in texts]
    except ValueError:
        raise ValueError(f"lower_bounds must be a comma-separated list of numbers, got {config.lower_bounds!r}") from None
    if not all(math.isfinite(bound) for bound in bounds):
        raise ValueError(f"lower_bounds must be finite numbers, got {config.lower_bounds!r}")
    if len(set(bounds)) != len(bounds):
        raise ValueError(f"lower_bounds repeats a value: {config.lower_bounds!r}")
    return bounds


def config_file_of(cls: type) -> ConfigFile:
    """What ``config=FILE`` takes for the command of ``cls`` (``TrainConfig`` or
    ``ExperimentConfig``): its own keys; skipped, which run the file came from (``out``,
    ``resume``, ``resume_step``, ``fast_forward``) and the other command's own keys (a train run's
    ``missingness`` and ``seed`` given to ``experiment``; an experiment's ``seeds`` and
    ``modes`` given to ``train``). A resumed run's own settings: its ``config.yaml``, an
    experiment's ``experiment.yaml``; ``resume=auto`` continues it where its ``checkpoints/``
    holds one."""
    own = {field.name for field in dataclasses.fields(cls)}
    every = own | {field.name for command in (TrainConfig, ExperimentConfig) for field in dataclasses.fields(command)}
    out = {TrainConfig: run_out, ExperimentConfig: experiment_out}[cls]
    settings = {TrainConfig: RUN_SETTINGS, ExperimentConfig: EXPERIMENT_SETTINGS}[cls]

    def holds_checkpoint(config) -> bool:
        from admissable_jax.checkpointing import Checkpoints  # orbax: imported where a command asks

        return bool(Checkpoints.steps_in(os.path.join(out(config), "checkpoints")))

    return ConfigFile(taken=frozenset(own - set(RUN_LOCATION)), skipped=frozenset((every - own) | set(RUN_LOCATION)),
                      resumed=lambda config: os.path.join(out(config), settings), holds_checkpoint=holds_checkpoint)


def default_num_envs(score_every: int) -> int:
    """The largest divisor of ``score_every`` up to 8 on a CPU or 128 on an accelerator
    (scoring happens after whole iterations, so ``num_envs`` must divide ζ)."""
    target = 8 if jax.default_backend() == "cpu" else 128
    return max(n for n in range(1, min(target, score_every) + 1) if score_every % n == 0)


def default_score_envs(num_episodes: int) -> int:
    """Scoring envs stepped at once: on a CPU, where a batched MJX step costs its batch size
    times a per-env cost (the physics steps large batches in pieces: ``EnvOptions.worlds_per_call``),
    a pool of 32 whose slots start the next episode as theirs end, so that finished episodes
    are not stepped until the longest ends (benchmarks/NOTES.md); on an accelerator every
    episode at once (a step costs nearly the same for any batch that fits)."""
    return min(num_episodes, 32) if jax.default_backend() == "cpu" else num_episodes


def check_sets(config: RunSettings) -> None:
    """ValueError in one line for a U that every round cannot score whole (more than
    MAX_CANDIDATE_SETS sets) without a pool, for a ``pool_size`` the beam search cannot fill,
    or one that is no smaller than U (the env's name must be valid)."""
    d = observation_size(canonical_env_name(config.env))
    if config.pool_size == 0:
        check_exact_size(d, config.k, config.include_empty_set, config.up_to_k,
                         remedy=f"score a pool of the worst sets a search finds with pool_size=P (P <= d = {d}), "
                                f"or use a smaller k")
        return
    num_sets = num_candidate_sets(d, config.k, up_to_k=config.up_to_k)
    if config.include_empty_set:
        raise ValueError("pool_size > 0 searches sets of features: it excludes include_empty_set=true")
    if config.pool_size >= num_sets:
        raise ValueError(f"pool_size={config.pool_size} is not below |U| = {num_sets}: score all sets with pool_size=0")
    if config.pool_size > d or 2 * config.k > d:
        raise ValueError(f"pool_size must be <= d = {d} and k <= d/2 (the beam search starts from the single features)")


def check_field_types(config, fields) -> None:
    """TypeError in one line for a field of ``fields`` whose value is not of its type (a bool
    is no int), ValueError for a float field that is not finite."""
    for field in fields:
        value = getattr(config, field.name)
        expected = {"int": int, "float": (int, float), "bool": bool, "str": str}[field.type]
        if not isinstance(value, expected) or (field.type == "int" and isinstance(value, bool)):
            raise TypeError(f"{field.name} must be {field.type}, got {value!r}")
        if field.type == "float" and not math.isfinite(value):
            raise ValueError(f"{field.name} must be a finite number, got {value!r}")


def validate(config: TrainConfig) -> None:
    """Raise ValueError/TypeError with a one-line message for any bad setting."""
    if not isinstance(config, TrainConfig):
        raise TypeError(f"expected a TrainConfig, got {type(config).__name__}")
    if isinstance(config.env, type):  # a class of one's own, given as itself: its name is what runs keep
        raise TypeError(f"env must be a name: env={config.env.__module__}:{config.env.__qualname__} names this class")
    check_field_types(config, dataclasses.fields(TrainConfig))
    canonical_env_name(config.env)
    env_physics(config.env, config.physics)
    parse_logger_names(config.logger)
    if config.score_estimator not in SCORE_ESTIMATORS:
        raise ValueError(f"score_estimator must be one of {', '.join(SCORE_ESTIMATORS)}, got {config.score_estimator!r}")
    if config.pool_ranker not in SCORE_ESTIMATORS:
        raise ValueError(f"pool_ranker must be one of {', '.join(SCORE_ESTIMATORS)}, got {config.pool_ranker!r}")
    if config.pool_size < 0:
        raise ValueError(f"pool_size must be >= 0 (0 = score all sets), got {config.pool_size}")
    if not 0 <= config.pool_explore <= 1:
        raise ValueError(f"pool_explore must be in [0, 1], got {config.pool_explore}")
    if config.missingness not in MODES:
        raise ValueError(f"missingness must be one of {', '.join(MODES)}, got {config.missingness!r}")
    positive = ("k", "score_every", "score_episodes", "score_horizon", "total_steps", "episode_length",
                "batch_size", "hidden_size", "hidden_layers", "buffer_size", "checkpoint_every", "keep_checkpoints")
    check_at_least_one(config, positive)
    for name in ("num_envs", "score_envs", "worlds_per_call"):
        if getattr(config, name) < 0:
            raise ValueError(f"{name} must be >= 0, got {getattr(config, name)}")
    if config.fast_forward and not config.resume:
        raise ValueError("fast_forward=true continues a run from its records: pass resume=true too")
    if config.resume_step < -1:
        raise ValueError(f"resume_step must be -1 (the latest checkpoint) or a checkpoint's env step, got {config.resume_step}")
    if config.resume_step != -1 and not config.resume:
        raise ValueError(f"resume_step={config.resume_step} picks the checkpoint a run continues from: pass resume=true too")
    if config.seed < 0:
        raise ValueError(f"seed must be >= 0, got {config.seed}")
    if config.time_limit < 0:
        raise ValueError(f"time_limit must be >= 0 (0 = no limit), got {config.time_limit}")
    if config.utd <= 0:
        raise ValueError(f"utd must be > 0, got {config.utd}")
    if config.epsilon <= 0:
        raise ValueError(f"epsilon must be > 0, got {config.epsilon}")
    if config.learning_rate <= 0:
        raise ValueError(f"learning_rate must be > 0, got {config.learning_rate}")
    if not 0 <= config.gamma <= 1:
        raise ValueError(f"gamma must be in [0, 1], got {config.gamma}")
    if not 0 < config.tau <= 1:
        raise ValueError(f"tau must be in (0, 1], got {config.tau}")
    if config.learning_starts < config.batch_size:
        raise ValueError(
            f"learning_starts ({config.learning_starts}) must be >= batch_size ({config.batch_size})"
        )
    if config.episode_length > 1000:
        raise ValueError("episode_length must be <= 1000 (the v5 limit)")
    fail_steps(config.fail_at, config.episode_length)
    if fail_steps(config.score_fail_at, config.episode_length, "score_fail_at") != (0,):
        if config.score_estimator != "rollout":
            raise ValueError(f"score_fail_at={config.score_fail_at} needs score_estimator=rollout: the critic values each "
                             "start with u hidden from it, not a sensor that fails later")
        spread_fail_steps(config.score_fail_at, config.score_episodes, names=("score_fail_at", "score_episodes"))


def setting_warnings(config: TrainConfig) -> list[str]:
    """What a resolved run's settings do that its keys do not say, one line each: a
    ``total_steps`` that is no multiple of ζ (rounded up), a ``learning_starts`` not below the
    run's env steps (SAC, learning once env steps pass it, never updates; a random-policy
    baseline may mean it), a ``utd`` whose
    ``num_envs · utd`` gradient steps per iteration is no whole number (rounded, at least 1),
    and a replay buffer that holds fewer transitions than one minibatch (``buffer_size`` as
    rounded: every minibatch, drawn with replacement, repeats the last few env steps)."""
    warnings = []
    if config.planned_steps != config.total_steps:
        warnings.append(f"the run trains {config.planned_steps:,} env steps: total_steps={config.total_steps} rounded up "
                        f"to a multiple of score_every={config.score_every}, as every interval ends in a scoring")
    if config.learning_starts >= config.planned_steps:
        warnings.append(f"learning_starts={config.learning_starts} is not below the run's {config.planned_steps} env "
                        "steps: SAC never updates, and every scoring scores the untrained policy (lower learning_starts "
                        "or raise total_steps)")
    updates, asked = config.updates_per_iteration, config.num_envs * config.utd
    if not math.isclose(updates, asked, rel_tol=1e-9):
        warnings.append(f"utd={number_text(float(config.utd))} with num_envs={config.num_envs} asks for {asked:.4g} "
                        f"gradient steps per iteration, which is rounded to {updates}: the run's utd is "
                        f"{updates / config.num_envs:.4g} (choose num_envs and utd whose product is a whole number)")
    capacity = buffer_capacity(config.buffer_size, config.num_envs)
    if capacity < config.batch_size:
        held = "" if capacity == config.buffer_size else f" (rounded to a multiple of num_envs={config.num_envs})"
        warnings.append(f"buffer_size={config.buffer_size} holds {capacity} transitions{held}, fewer than one minibatch "
                        f"(batch_size={config.batch_size}): every minibatch repeats transitions, all from the last "
                        f"{capacity} env steps (raise buffer_size)")
    return warnings
