"""``python -m admissable_jax.audit``: its settings (:class:`AuditConfig`), what they name (a
run, an experiment's pairs, a run's checkpoints, a Python policy on a Gymnasium env), the
audits that follow and where each one's files go."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

from admissable_jax.audit.report import BY_FAILURE_TIME, compare_modes, compare_modes_by_failure_time, \
    comparison_chart, dropout_line, failure_time_chart_by_mode, pair_curves, robustness_chart, robustness_table, \
    shapley_order, training_failure_source, write_audit
from admissable_jax.audit.sets import AuditResult, audit, audit_gymnasium, audit_sizes, check_audit_size, \
    check_failing_audit, check_search, gymnasium_features, rollout_sets, shapley_plan
from admissable_jax.cli import enable_compilation_cache, parse_args, reporting, run_from_cli, setting
from admissable_jax.errors import make_directory, remove_if_unused
from admissable_jax.method import check_fail_at, fail_steps, set_sizes
from admissable_jax.run_directory import experiment_pairs, is_experiment, same_policy_record
from admissable_jax.scoring import SCORE_ESTIMATORS
from admissable_jax.scoring.attribution import MIN_ORDERS, ShapleyPlan
from admissable_jax.scoring.dropout import DropoutPlan, check_masks, parse_rates, plan_dropout

if TYPE_CHECKING:  # for the annotations only
    import numpy as np

    from admissable_jax.envs import MjxEnv
    from admissable_jax.policies import TrainedPolicy
    from admissable_jax.training import Trainer



@dataclasses.dataclass
class AuditConfig:
    run_dir: str = setting("", "a train run directory, an experiment pair's, or an experiment's folder (every pair, "
                               "then comparison.md of the modes); may be given first, without run_dir=. Several (one "
                               "after another, or comma separated; folders of runs too): each run audited, then "
                               "comparison.md of their curves (mode and the settings they differ in), as plot groups them")
    k: str = setting("", "set sizes to audit, comma separated (e.g. 1,2); default: the sizes of the run's U (its k, "
                         "or 1 to k with up_to_k), 1 with policy=")
    episodes: int = setting(50, "N: deterministic episodes per set (the CI narrows as 1/sqrt(N))")
    out: str = setting("", "where the report goes (default RUN_DIR/audit-step<STEP>; policy=: audit-<ENV_ID>-<NAME>, "
                           "beside the file for an exported policy)")
    step: int = setting(-1, "the checkpoint (env step) to audit; -1 = the latest")
    best: bool = setting(False, "audit the policy the run kept at its best scoring (best_policy.npz: training's "
                                "highest min_u a_u, an estimate that reads high) instead of a checkpoint; an "
                                "experiment: each pair's, into audit-best/")
    seed: int = setting(0, "seed of the N start states")
    top: int = setting(10, "worst sets listed per k in report.md")
    slots: int = setting(0, "envs stepped at once, each starting the next episode as its own ends (0 = as training "
                            "scores: 32 on a CPU, every episode at once, at most 4096, on an accelerator; with "
                            "policy=: 8 Gymnasium envs)")
    score_estimator: str = setting("rollout", "rollout (the paper's a_u) | critic | horizon: the run's critic's discounted "
                                              "value (see admissable_jax.scoring)")
    score_horizon: int = setting(100, "H of score_estimator=horizon")
    search: str = setting("exact", "exact (every set of each k) | beam (k > 1: beam search for the worst sets, "
                                   "finalists confirmed by score_estimator)")
    beam_width: int = setting(4, "b of search=beam: sets kept per level, and finalists per k")
    ranker: str = setting("rollout", "what ranks the candidates of search=beam: rollout | critic | horizon")
    steps: str = setting("", "audit several checkpoints of one run: 'all' or a comma list of env steps; each into "
                             "its folder, then robustness_over_training.md/.png (worst and mean a_u per k by step)")
    policy: str = setting("", "instead of a run: MODULE:NAME, any Python policy masked_obs_batch -> actions "
                              "(Stable-Baselines3, CleanRL, PyTorch) to audit on the Gymnasium env gym=; or FILE.npz, "
                              "a policy python -m admissable_jax.export wrote (gym= and k= default to its run's)")
    gym: str = setting("", "with policy=: the Gymnasium env id (Hopper-v5, or any other; hopper names Hopper-v5 as "
                           "env= does) the policy acts in")
    tell_apart: bool = setting(False, "audit twice: a pilot of `episodes` per set, then, from fresh start states, as "
                                      "many episodes per set as the pilot says tell the worst set of each k from the "
                                      "runner-up (80% power; at most 1000)")
    shapley: str = setting("0", "what each feature is worth: Shapley values of the return over the visible features; "
                                "exact (every coalition, d <= 20), or M random feature orders (exact where the 2^d "
                                "coalitions are fewer); 0 = none")
    dropout: str = setting("", "random sensor failure: failure rates p, comma separated (e.g. 0.05,0.1,0.2): the "
                               "expected return when each feature fails with probability p for a whole episode, "
                               "independently, from dropout_masks masks per rate; '' = none")
    dropout_masks: int = setting(20, "M: masks drawn per dropout rate (the interval narrows as 1/sqrt(M))")
    fail_at: str = setting("0", "the env step of each episode at which the hidden features' sensors fail, every feature "
                                "seen before it (a sensor that dies mid-run); 0 = hidden from the start, as the paper "
                                "and training hide them. Rollouts only; the default folders end in -fail<T>. A comma "
                                "list (0,50,100) audits the policy, or an experiment's pairs, at each, then "
                                "failure_times.md/.png")


def _ks(text: str, trained_k: int = 1, up_to_k: bool = False) -> tuple[int, ...]:
    """The set sizes ``k=`` asks for; where it is empty, those of the sets the policy trained
    against (a run's k and up_to_k; a Python policy's: 1)."""
    if not text.strip():
        return tuple(set_sizes(trained_k, up_to_k))
    try:
        ks = tuple(sorted({int(part) for part in text.split(",") if part.strip()}))
    except ValueError:
        raise ValueError(f"k must be a comma list of set sizes, e.g. 1,2; got {text!r}") from None
    if not ks or ks[0] < 1:
        raise ValueError(f"k must be a comma list of set sizes >= 1, got {text!r}")
    return ks


def _sizes(ks: tuple[int, ...]) -> str:
    return ",".join(map(str, ks))


def check_audit_config(config: AuditConfig) -> None:
    if config.policy or config.gym:
        if config.run_dir or not config.policy or not (config.gym or config.policy.endswith(".npz")):
            raise ValueError("a Python policy is audited with policy=MODULE:NAME and gym=ENV_ID (an exported policy: "
                             "policy=FILE.npz), and no run directory")
        if config.score_estimator != "rollout" or config.search != "exact":
            raise ValueError("a Python policy is audited by rollouts of every set (it has no critic to estimate with)")
    elif not config.run_dir:
        raise ValueError("give the run directory: python -m admissable_jax.audit RUN_DIR [k=1,2] [episodes=50]")
    if _several_runs(config) and config.steps:
        raise ValueError("several runs are audited each at one checkpoint (the latest, step= or best=true): give steps= "
                         "one run")
    if config.steps and (config.step >= 0 or config.policy or is_experiment(config.run_dir)):
        raise ValueError("steps= audits several checkpoints of one run (a train run or one pair of an experiment), "
                         "without step= or policy=")
    if config.best and (config.step >= 0 or config.steps or config.policy):
        raise ValueError("best=true audits the policy a run kept at its best scoring (an experiment: each pair's), "
                         "without step=, steps= or policy=")
    _ks(config.k)
    if config.top < 1:
        raise ValueError(f"top must be at least 1, got {config.top}")
    if config.episodes < 2:
        raise ValueError("episodes must be at least 2 for a confidence interval")
    if config.slots < 0:
        raise ValueError(f"slots must be >= 0, got {config.slots}")
    if config.seed < 0 or config.step < -1:
        raise ValueError(f"seed must be >= 0 and step an env step or -1 (the latest), got seed={config.seed}, "
                         f"step={config.step}")
    if config.score_estimator not in SCORE_ESTIMATORS or config.score_horizon < 1:
        raise ValueError(f"score_estimator must be one of {', '.join(SCORE_ESTIMATORS)} and score_horizon >= 1")
    check_search(config.search, config.beam_width, config.ranker)
    _shapley(config.shapley)
    if parse_rates(config.dropout):
        check_masks(config.dropout_masks)
    times = fail_steps(config.fail_at)
    check_failing_audit(max(times), config.score_estimator, config.ranker if config.search == "beam" else "rollout")
    if len(times) > 1 and config.steps:
        raise ValueError("a list of fail_at audits one checkpoint (of a run, of an experiment's pairs, or policy=): give "
                         "steps= one fail_at")


def _fail_at(config: AuditConfig) -> int:
    """The env step at which the sensors fail in one audit."""
    (time,) = fail_steps(config.fail_at)
    return time


def _failing(config: AuditConfig) -> str:
    """The default folder's ending: ``-fail<T>`` where the sensors fail at env step T."""
    time = _fail_at(config)
    return f"-fail{time}" if time else ""


def _shapley(text: str) -> int | str:
    """``shapley=``: 0 (none), ``exact``, or a number M >= 4 of feature orders."""
    if text.strip() == "exact":
        return "exact"
    try:
        orders = int(text)
    except ValueError:
        orders = -1
    if orders == 0 or orders >= MIN_ORDERS:
        return orders
    raise ValueError(f"shapley must be 0 (none), exact, or at least {MIN_ORDERS} feature orders, got {text!r}")


class GymnasiumPolicy(NamedTuple):
    """What ``policy=`` names, ready to audit on a Gymnasium env."""

    policy: Callable[[np.ndarray], Any]  # masked_obs_batch -> actions
    name: str  # the default folder's
    gym: str  # the Gymnasium env id (or our env's name, as env= takes it)
    ks: tuple[int, ...]
    source: dict[str, str]  # for the report, beside the env and the policy
    feature_names: list[str] | None  # None: our env's names, or the indices


def audit_python_policy(config: AuditConfig) -> tuple[AuditResult, list[str]]:
    """Audit ``config.policy`` on the Gymnasium env ``config.gym`` by
    :func:`~admissable_jax.audit.sets.audit_gymnasium`: MODULE:NAME (importable from here),
    or an exported policy's FILE.npz (:mod:`admissable_jax.exported_policy`), whose run
    names the env and the set sizes where ``gym=`` and ``k=`` do not; write the report into
    ``config.out`` (default ``audit-<ENV_ID>-<NAME>``, beside an exported policy's file).
    ``gym=`` may name one of our envs as ``env=`` does (``hopper`` for Hopper-v5)."""
    import gymnasium

    from admissable_jax.envs.catalog import gymnasium_env_id

    check_audit_config(config)
    audited = _exported(config) if config.policy.endswith(".npz") else _imported(config)
    config = dataclasses.replace(config, gym=gymnasium_env_id(audited.gym))
    d = gymnasium_features(config.gym)
    audit_sizes(audited.ks, d)  # before anything is written
    check_fail_at(_fail_at(config), gymnasium.spec(config.gym).max_episode_steps)
    dropout = _dropout(config, d)
    check_audit_size(config.gym, d, audited.ks, config.episodes, None, plan=_plan(config, d), dropout=dropout)
    out = config.out or _policy_folder(config, f"audit-{config.gym}-{audited.name}{_failing(config)}")
    source = {"Gymnasium env": config.gym, "policy": config.policy, **audited.source}  # checked, then recorded
    with _audit_folder(out, source):
        with reporting(f"auditing {config.policy} on {config.gym} for k={_sizes(audited.ks)} "
                       f"({_episodes_asked(config)})"):
            result = audit_gymnasium(config.gym, _named(audited.policy, config.policy), audited.ks, config.episodes,
                                     num_envs=config.slots or 8, seed=config.seed,
                                     feature_names=audited.feature_names if len(audited.feature_names or ()) == d
                                     else None, shapley=_shapley(config.shapley), progress=True,
                                     tell_apart=config.tell_apart, dropout=dropout, fail_at=_fail_at(config))
        result = dataclasses.replace(result, source=source)  # audit_gymnasium's own: its first two keys
        return result, write_audit(result, out, config.top)


def _imported(config: AuditConfig) -> GymnasiumPolicy:
    """``policy=MODULE:NAME``, imported; ValueError in one line where it does not load or
    is no callable."""
    import importlib

    module_name, _, name = config.policy.partition(":")
    if not module_name or not name:
        raise ValueError(f"policy must be MODULE:NAME (a callable in an importable module) or an exported policy's "
                         f"FILE.npz, got {config.policy!r}")
    try:
        policy = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"cannot load policy={config.policy}: {error}") from None
    if not callable(policy):
        raise ValueError(f"policy={config.policy} is not callable (its type: {type(policy).__name__}): give a function "
                         "masked_obs_batch -> actions")
    return GymnasiumPolicy(policy, _policy_name(config.policy), config.gym, _ks(config.k), {}, None)


def _exported(config: AuditConfig) -> GymnasiumPolicy:
    """``policy=FILE.npz``, an exported policy: the Gymnasium env and set sizes its run
    trained on where ``gym=`` and ``k=`` do not say, its features' names, and where it came
    from for the report."""
    from admissable_jax.exported_policy import ExportedPolicy

    exported = ExportedPolicy.load(config.policy)
    trained = exported.source
    gym = config.gym or trained.get("gymnasium_id")
    if not gym:
        raise ValueError(f"{config.policy} is a policy of {trained.get('env')}, which has no Gymnasium env: give gym=")
    best = trained.get("best_min_score")
    came_from = (f"{trained.get('run')} ({trained.get('missingness')}, seed {trained.get('seed')}) at env step "
                 f"{trained.get('env_steps')}" + ("" if best is None else f", its best scoring (training's min_u a_u "
                                                                          f"{best:.1f})"))
    return GymnasiumPolicy(exported.masked, _policy_name(config.policy), gym,
                           _ks(config.k, trained.get("k", 1), trained.get("up_to_k", False)),
                           {"exported from": came_from, **training_failure_source(trained)},
                           list(exported.observation_names))


def _policy_name(policy: str) -> str:
    """The name ``policy=`` gives a default folder: MODULE:NAME's NAME, or the file's stem."""
    return os.path.splitext(os.path.basename(policy))[0] if policy.endswith(".npz") else policy.partition(":")[2]


def _policy_folder(config: AuditConfig, name: str) -> str:
    """Where ``policy=``'s default folder ``name`` goes: beside an exported policy's file (as
    ``video``'s), where files of the same name from different runs (``export`` names each
    ``policy-step<N>.npz``) keep their audits apart; a Python policy's, in the current folder."""
    return os.path.join(os.path.dirname(config.policy), name) if config.policy.endswith(".npz") else name


# What names the audited policy in an audit's source: a run's checkpoint (or its best), or a
# policy on a Gymnasium env (an exported one by the run and step it came from).
POLICY_KEYS = ("run", "checkpoint (env step)", "kept as", "Gymnasium env", "exported from")


def _audited_policy(source: dict[str, Any]) -> tuple:
    """The policy an audit with ``source`` audited (:data:`POLICY_KEYS`; ``policy=``'s text
    where it was not exported, since an exported file's path may be given either way)."""
    return tuple(source.get(key) for key in POLICY_KEYS) + (
        None if "exported from" in source else source.get("policy"),)


def _check_free_for(out: str, source: dict[str, Any]) -> None:
    """FileExistsError in one line where ``out`` holds the audit of another policy than
    ``source``'s (a second Python policy of the same name, an ``out=`` given twice): a
    finished audit is never written over by another policy's; the same policy's is (an audit
    again, with other settings; of its run moved, linked or copied since)."""
    path = os.path.join(out, "audit.json")
    if not os.path.isfile(path):
        return
    try:
        with open(path) as file:
            recorded = json.load(file)["source"]
        earlier = _audited_policy(recorded)
    except (OSError, ValueError, KeyError, TypeError):
        earlier = None
    if earlier != _audited_policy(source) and not (
            earlier is not None and same_policy_record(recorded, source, out)):
        whose = "another policy's audit" if earlier is None else (
            f"the audit of another policy ({', '.join(str(part) for part in earlier if part is not None)})")
        raise FileExistsError(f"{out} holds {whose}: it is left as it is; give another out= (or remove it)")


@contextlib.contextmanager
def _audit_folder(out: str, source: dict[str, Any]):
    """The audit folder ``out`` for the policy of ``source``, made before the rollout, so
    that an unusable path, or one holding another policy's audit, fails first. If the audit
    stops (Ctrl-C, an error) before writing into a folder it made, the folder goes too."""
    _check_free_for(out, source)
    made_here = not os.path.exists(out)
    make_directory(out, "audit folder")
    try:
        yield
    except BaseException:
        if made_here:
            remove_if_unused(out, ())
        raise


def _episodes_asked(config: AuditConfig) -> str:
    return (f"a pilot of {config.episodes} episodes per set, then as many as tell the worst sets apart"
            if config.tell_apart else f"{config.episodes} episodes per set")


def _run_paths(config: AuditConfig) -> list[str]:
    """The run directories ``run_dir`` names: one, or several comma separated."""
    return [path for path in config.run_dir.split(",") if path]


def _several_runs(config: AuditConfig) -> bool:
    """Whether ``run_dir`` names several runs, audited each and compared (:func:`audit_runs`)."""
    return len(_run_paths(config)) > 1


def audit_run(config: AuditConfig) -> tuple[AuditResult, list[str]]:
    """Audit the run in ``config.run_dir`` at ``config.step``; write the report."""
    check_audit_config(config)
    from admissable_jax.policies import load_policy, requested_step

    policy = load_policy(config.run_dir, requested_step(config.step, config.best))
    return _audit_policy(config, policy, _audit_env(config, policy), policy.trainer)


def _named(policy: Callable[[np.ndarray], Any], name: str) -> Callable[[np.ndarray], Any]:
    """``policy``, whose own exception ends the audit in one line that names it (a usage
    error of the command), not in a traceback through the rollout; a Ctrl-C passes as it is."""

    def call(masked_obs_batch: np.ndarray) -> Any:
        try:
            return policy(masked_obs_batch)
        except Exception as error:
            first_line = next(iter(str(error).splitlines()), "")
            raise ValueError(f"policy={name} raised {type(error).__name__}: {first_line}") from error

    call.__name__ = name  # what the report calls the policy
    return call


def _audit_env(config: AuditConfig, policy: TrainedPolicy) -> MjxEnv:
    """The run's env, sized for every episode the audit steps at once (at most ``slots``)."""
    from admissable_jax.envs import make_env

    train = policy.config
    return make_env(train.env, physics=train.physics, episode_length=train.episode_length,
                    max_batch=_slots(config, policy))


def _slots(config: AuditConfig, policy: TrainedPolicy) -> int:
    """Episodes stepped at once: the most (sets + clean) × N one of its rollouts steps
    (:func:`~admissable_jax.audit.sets.rollout_sets`), at most ``slots``, or as many as
    training's scoring steps (:func:`~admissable_jax.config.default_score_envs`: 32 on a CPU,
    where a batched step's cost grows with its batch; all on an accelerator), at most 4096."""
    from admissable_jax.config import default_score_envs

    d = policy.observation_size
    num_sets = rollout_sets(d, _ks(config.k, policy.config.k, policy.config.up_to_k), config.search, config.beam_width,
                            _plan(config, d), _dropout(config, d))
    episodes = (num_sets + 1) * config.episodes
    return min(episodes, config.slots) if config.slots else min(default_score_envs(episodes), 4096)


def _plan(config: AuditConfig, d: int) -> ShapleyPlan | None:
    return shapley_plan(d, _shapley(config.shapley), config.seed)


def _dropout(config: AuditConfig, d: int) -> DropoutPlan | None:
    return plan_dropout(d, parse_rates(config.dropout), config.dropout_masks, config.seed)


def _audit_policy(config: AuditConfig, policy: TrainedPolicy, env: MjxEnv,
                  trainer: Trainer) -> tuple[AuditResult, list[str]]:
    """Audit ``policy``'s networks with ``env`` and ``trainer``'s policy and critic functions
    (an experiment passes its first pair's to every pair, so the rollout compiles once)."""
    import jax

    from admissable_jax.envs import observation_names

    best = policy.best_min_score is not None
    out = config.out or os.path.join(config.run_dir, f"audit-{'best-' * best}step{policy.step}{_failing(config)}")
    train = policy.config
    check_fail_at(_fail_at(config), train.episode_length)
    d = policy.observation_size
    ks = audit_sizes(_ks(config.k, train.k, train.up_to_k), d)  # before the audit starts
    dropout = _dropout(config, d)
    check_audit_size(train.env, d, ks, config.episodes, config.search, config.beam_width, _plan(config, d), dropout)
    source = {"run": os.path.abspath(config.run_dir), "checkpoint (env step)": policy.step,
              **({"kept as": f"its best scoring (training's min_u a_u {policy.best_min_score:.1f})"} if best else {}),
              "mode": train.missingness, "seed": train.seed,
              **({"lower_bound": train.lower_bound} if train.missingness == "adversarial" else {}),
              **training_failure_source(vars(train))}
    with _audit_folder(out, source):
        which = f"the best policy (env step {policy.step})" if best else f"checkpoint {policy.step}"
        with reporting(f"auditing {which} of {train.env} for k={_sizes(ks)} ({config.search} search, "
                       f"{_episodes_asked(config)}, {env.physics_name} physics on {jax.default_backend()}; "
                       f"compiling included)"):
            result = audit(env, trainer.policy, policy.actor_params, ks, config.episodes, config.seed,
                           _slots(config, policy), observation_names(train.env), source, config.score_estimator,
                           trainer.critic_values, policy.critic_params, config.score_horizon, train.gamma,
                           config.search, config.beam_width, config.ranker, _shapley(config.shapley), progress=True,
                           tell_apart=config.tell_apart, dropout=dropout, fail_at=_fail_at(config))
        return result, write_audit(result, out, config.top)


def audit_over_training(config: AuditConfig) -> tuple[list[AuditResult], list[str]]:
    """Audit the run in ``config.run_dir`` at several checkpoints (``steps``: ``all`` or a
    comma list of env steps), each into its own folder as :func:`audit_run` does, the
    rollout compiled once; then ``robustness_over_training.md`` and ``.png`` (in
    ``RUN_DIR/audit-over-training`` or ``out``): per checkpoint and k, the worst a_u and its
    set and the mean a_u over the sets, beside the clean return. Training records a_u for
    the sets it scores (k = 1 by default); this says when robustness to other k came."""
    check_audit_config(config)
    from admissable_jax.policies import checkpoint_steps

    saved = checkpoint_steps(config.run_dir)
    try:
        steps = saved if config.steps == "all" else sorted({int(part) for part in config.steps.split(",") if part.strip()})
    except ValueError:
        raise ValueError(f"steps must be 'all' or a comma list of env steps, got {config.steps!r}") from None
    missing = sorted(set(steps) - set(saved)) or ([] if steps else ["(none)"])
    if missing:
        raise ValueError(f"no checkpoint at {', '.join(map(str, missing))} in {config.run_dir}; "
                         f"saved: {', '.join(map(str, saved)) or 'none'}")
    out = config.out or os.path.join(config.run_dir, f"audit-over-training{_failing(config)}")
    results, written = _audit_each([(dataclasses.replace(config, out=os.path.join(out, f"step{step}")), step)
                                    for step in steps])
    written.append(robustness_chart(results, os.path.join(out, "robustness_over_training.png")))
    written.append(os.path.join(out, "robustness_over_training.md"))
    with open(written[-1], "w") as file:
        file.write(robustness_table(results) + "\n![worst and mean a_u per k by checkpoint]"
                   "(robustness_over_training.png)\n")
    return results, written


def _audit_each(jobs: list[tuple[AuditConfig, int | str | None]]) -> tuple[list[AuditResult], list[str]]:
    """Audit each (config, checkpoint step; None = the latest, "best" = the best scoring's) of ``jobs`` into its folder,
    all with the first one's env and policy function (an experiment's pairs, or one run's
    checkpoints, share the env and the network shapes), so the rollout compiles once."""
    from admissable_jax.policies import load_policy

    results, written, env, trainer = [], [], None, None
    for config, step in jobs:
        policy = load_policy(config.run_dir, step)
        if env is None:
            env, trainer = _audit_env(config, policy), policy.trainer
        result, files = _audit_policy(config, policy, env, trainer)
        results.append(result)
        written += files
    return results, written


def audit_failure_times(config: AuditConfig) -> tuple[list[AuditResult], list[str]]:
    """Audit one policy (a run's checkpoint, its best, or ``policy=``), every pair of an
    experiment, or several runs, once per env step in ``fail_at`` (a comma list), each into
    ``<out>/fail<T>/`` as a single audit (each compiles its rollout: the step is part of the
    program); then ``failure_times.md`` and ``.png`` (in ``out``; default
    ``RUN_DIR/audit-failure-times`` with ``-best`` or ``-step<STEP>`` where asked,
    ``audit-<NAME>-failure-times`` for ``policy=`` (beside an exported policy's file),
    ``audit-comparison-failure-times`` for several runs): for one policy, per failure step
    and k, the worst a_u and its set and the mean a_u over the sets, beside the clean return,
    and each single feature's a_u by failure step; for an experiment or several runs, the
    modes' (curves') worst a_u by failure step, and adversarial − uniform at each. Training
    hides u from an episode's start; this says what a sensor lost later costs, and which."""
    check_audit_config(config)
    which = "-best" if config.best else f"-step{config.step}" if config.step >= 0 else ""
    out = config.out or (_policy_folder(config, f"audit-{_policy_name(config.policy)}-failure-times") if config.policy else
                         f"audit-comparison-failure-times{which}" if _several_runs(config) else
                         os.path.join(config.run_dir, f"audit-failure-times{which}"))
    jobs = [dataclasses.replace(config, fail_at=str(time), out=os.path.join(out, f"fail{time}"))
            for time in fail_steps(config.fail_at)]
    if config.policy:
        audits = [audit_python_policy(job) for job in jobs]
        results, written = [result for result, _ in audits], [path for _, files in audits for path in files]
    elif is_experiment(config.run_dir) or _several_runs(config):
        audits = [(audit_runs if _several_runs(config) else audit_experiment)(job) for job in jobs]
        by_time = {_fail_at(job): pairs for job, (pairs, _) in zip(jobs, audits)}
        written = [path for _, files in audits for path in files]
        written.append(failure_time_chart_by_mode(by_time, os.path.join(out, "failure_times.png")))
        written.append(os.path.join(out, "failure_times.md"))
        with open(written[-1], "w") as file:
            file.write(compare_modes_by_failure_time(by_time) + "\n![the worst set by failure step, per mode]"
                       "(failure_times.png)\n")
        return [result for pairs in by_time.values() for result in pairs], written
    else:
        from admissable_jax.policies import requested_step

        results, written = _audit_each([(job, requested_step(config.step, config.best)) for job in jobs])
    written.append(robustness_chart(results, os.path.join(out, "failure_times.png"), BY_FAILURE_TIME))
    written.append(os.path.join(out, "failure_times.md"))
    with open(written[-1], "w") as file:
        file.write(robustness_table(results, BY_FAILURE_TIME) + "\n![worst and mean a_u per k, and each feature's, by "
                   "failure time](failure_times.png)\n")
    return results, written


def audit_experiment(config: AuditConfig) -> tuple[list[AuditResult], list[str]]:
    """Audit every (seed, mode) pair of the experiment in ``config.run_dir`` at the same
    checkpoint (``best=true``: each at its own best scoring, into ``audit-best``), each into its
    own folder as :func:`audit_run` does (under ``out`` if given),
    then compare the modes in ``comparison.md``: per k, each pair's worst a_u and its mean
    a_u over the sets, mean ± 95% t-interval over seeds per mode, and adversarial − uniform
    on both with Welch's interval. It
    answers what the paper's Figure 1 cannot: does training against one missing feature
    also protect against two?"""
    check_audit_config(config)
    from admissable_jax.policies import requested_step

    root = config.run_dir
    step = requested_step(config.step, config.best)
    pair_out = lambda pair: os.path.join(config.out, os.path.basename(pair)) if config.out else ""
    results, written = _audit_each([(dataclasses.replace(config, run_dir=pair, out=pair_out(pair)), step)
                                    for pair in experiment_pairs(root)])
    audited = "audit-best" if config.best else f"audit-step{results[0].source['checkpoint (env step)']}"
    return results, written + _write_comparison(results, config.out or os.path.join(root, audited + _failing(config)))


def audit_runs(config: AuditConfig) -> tuple[list[AuditResult], list[str]]:
    """Audit each of several runs (``run_dir``'s comma list: train runs, experiments' pairs,
    folders of them) as :func:`audit_run` does, each into its own folder, then compare their
    curves in ``comparison.md`` (in ``out``; default ``audit-comparison`` with ``-fail<T>``
    where the sensors fail mid-episode): a curve is a mode and the settings in which the runs
    differ (:func:`~admissable_jax.results.label_variants`, as ``plot`` names its curves), its
    runs its seeds. Runs trained with ``fail_at`` beside runs trained without, or with
    ``score_fail_at``, compared by one command."""
    check_audit_config(config)
    from admissable_jax.results import find_runs, label_variants, load_runs

    runs = label_variants(load_runs(find_runs(_run_paths(config))))
    envs = sorted({run.env for run in runs})
    if len(envs) > 1:
        raise ValueError(f"the runs compared must share one env, got {', '.join(envs)}: audit each env's apart")
    results, written = [], []
    for run in runs:
        result, files = audit_run(dataclasses.replace(config, run_dir=run.path, out=""))
        baseline = f"uniform, {run.baseline_variant}" if run.baseline_variant else "uniform"  # (Run.curve's form)
        results.append(dataclasses.replace(result, source={**result.source, "curve": run.curve, "baseline": baseline}))
        written += files
    return results, written + _write_comparison(results, config.out or f"audit-comparison{_failing(config)}")


def _write_comparison(results: list[AuditResult], out: str) -> list[str]:
    """``comparison.md`` and ``comparison.png`` of audited pairs or runs, by curve, into ``out``."""
    make_directory(out, "audit folder")
    written = [comparison_chart(results, os.path.join(out, "comparison.png")), os.path.join(out, "comparison.md")]
    with open(written[-1], "w") as file:
        file.write(compare_modes(results) + "\n![worst a_u per k and mode](comparison.png)\n")
    return written


def main(argv: list[str]) -> int:
    paths = [arg for arg in argv if "=" not in arg and not arg.startswith("-")]
    if len(paths) > 1:  # several runs, one after another: run_dir's comma list
        argv = [",".join(paths), *[arg for arg in argv if arg not in paths]]
    config = parse_args(AuditConfig, argv, "admissable_jax.audit",
                        "Which sensors break a policy? a_u of every set of k hidden features, with CIs, on one page.",
                        validate=check_audit_config, positional="run_dir")
    enable_compilation_cache()
    several_runs = _several_runs(config)
    experiment = several_runs or (bool(config.run_dir) and is_experiment(config.run_dir))  # pairs by curve
    several_times = len(fail_steps(config.fail_at)) > 1
    command = (audit_failure_times if several_times else audit_python_policy if config.policy
               else audit_over_training if config.steps else audit_runs if several_runs
               else audit_experiment if experiment else audit_run)
    outcome, status = run_from_cli(command, config, interrupted="interrupted: the audit in progress wrote nothing; "
                                                                "audit folders finished before it are kept")
    if status:
        return status
    several = experiment or config.steps or several_times  # audits, then a page that sets them side by side
    results, written = outcome if several else ([outcome[0]], outcome[1])
    for result, curve in zip(results, pair_curves(results) if experiment else [""] * len(results)):
        pair = (f"{f'fail_at {result.fail_at}, ' * several_times}{curve} seed {result.source['seed']}: " if experiment else
                f"step {result.source['checkpoint (env step)']}: " if config.steps else
                f"fail_at {result.fail_at}: " if several_times else "")
        if result.pilot is not None:
            print(f"{pair}N = {result.pilot['chosen']} episodes per set, chosen by a pilot of {result.pilot['episodes']}")
        if result.fail_at and result.ended_before_failing == len(result.clean_lengths):
            print(f"{pair}warning: every clean episode had ended by env step {result.fail_at}, where the sensors fail: "
                  "the sets' returns are the clean one's; give a smaller fail_at", file=sys.stderr)
        for k in result.sets:
            print(f"{pair}{result.worst_line(k)}")
        if result.shapley is not None:
            attribution, top = result.shapley, shapley_order(result.shapley)[0]
            print(f"{pair}shapley: {result.feature_names[top]} ({top}) worth most: φ {attribution.values[top]:.1f} ± "
                  f"{attribution.ci95[top]:.1f} of v(all) − v(none) {attribution.full - attribution.blind:.1f}; "
                  f"hidden alone it costs {attribution.leave_one_out[top]:.1f} ({attribution.method})")
        if result.dropout is not None:
            print(f"{pair}{dropout_line(result)}")
    if several:
        with open(written[-1]) as file:
            print(file.read())
        each = "run" if several_runs else "pair" if experiment else "checkpoint" if config.steps else "failure time"
        print(f"wrote each {each}'s report, audit.json and figures into its audit folder, and {written[-1]}")
    else:
        print(f"wrote {', '.join(written)}")
    return 0

