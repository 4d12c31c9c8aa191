"""Which sensors break a policy? A robustness audit over every set of k hidden features.

    python -m admissable_jax.audit RUN_DIR k=1,2 episodes=50 out=DIR [step=N]
    python -m admissable_jax.audit EXPERIMENT_DIR k=1,2      # every pair, then comparison.md
    python -m admissable_jax.audit policy=MODULE:NAME gym=Hopper-v5 k=1,2   # any Python policy

For every u with |u| in ``k`` (all C(d, |u|) sets, scored exactly: one batched rollout for
all of them and the clean case, N = ``episodes`` deterministic episodes each from the same N
start states, as the paper scores), the audit reports a_u with its 95% confidence interval
(Student's t over the N returns) and the drop from the clean return in %. It writes

- ``DIR/report.md``: the worst sets per k, with the env's feature names, on one page;
- ``DIR/audit.json``: every number (every set's a_u, CI, drop, the N returns, and its gap to the worst);
- ``DIR/scores_k1.png``: a bar chart of a_u per hidden feature (k = 1);
- ``DIR/pairs_k2.png``: a d × d heatmap of a_ij (k = 2).

Is the worst set really the worst, or did N episodes not tell it apart? Each row also gives
its a_u's gap above the worst with a 95% interval, paired episode by episode (every set's
episode i starts from one state, so the gap carries no reset noise; Welch's t for a Gymnasium
env's own resets), and the report names the sets not told apart from the worst, with about
how many episodes per set would tell the worst from the runner-up; ``tell_apart=true`` audits
with that many (a pilot of ``episodes`` per set chooses N, a second audit from fresh start
states is written).

``shapley=M`` (or ``exact``) adds what each feature is worth to the policy: its Shapley value
in the game whose coalitions are the visible features (:mod:`admissable_jax.scoring.attribution`;
exact where the 2^d coalitions are fewer than M random feature orders would value), beside the loss
of hiding it alone, in the same rollout; ``DIR/shapley.png`` and a section of the report.

``score_estimator=critic`` or ``horizon`` audits with the run's critic instead (cheaper;
discounted values, see :mod:`admissable_jax.scoring`); the report says which.

Where C(d, k) sets are too many (Ant: 5,460 pairs), ``search=beam`` finds the worst sets of
each k > 1 by beam search of width ``beam_width`` (:mod:`admissable_jax.scoring.set_search`),
ranking the candidates by ``ranker`` (rollout, or the critic's cheaper estimates), and
scores only the finalists by ``score_estimator`` (by default rollouts confirm them): at most
d + (k − 1) · b · d sets ranked instead of C(d, k). k = 1 is always scored exactly.

Given an experiment's folder, every pair is audited so (into ``PAIR/audit-step<STEP>``, or
``out/PAIR``) and ``comparison.md`` (in ``EXPERIMENT/audit-step<STEP>`` or ``out``) sets the
modes side by side per k: each pair's worst a_u and mean a_u over the sets, mean ± 95%
interval over seeds, and adversarial − uniform with Welch's interval; ``comparison.png``
draws the worst
(:func:`audit_experiment`).

In Python, :func:`audit` takes any JAX ``policy_fn(params, masked_obs) -> action`` on any of
our envs, :func:`audit_gymnasium` any Python policy on any Gymnasium env (Stable-Baselines3,
CleanRL, PyTorch), and :func:`write_audit` writes either's files.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import os
import sys
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm.auto import tqdm

from admissable_jax.cli import enable_compilation_cache, parse_args, reporting, run_from_cli, setting
from admissable_jax.errors import make_directory
from admissable_jax.method import candidate_sets, num_candidate_sets
from admissable_jax.results import Difference, estimate, mean_and_interval, seeds_sentence
from admissable_jax.scoring import SCORE_ESTIMATORS
from admissable_jax.scoring.attribution import MIN_ORDERS, ShapleyAttribution, ShapleyPlan, plan_shapley, \
    shapley_attribution
from admissable_jax.scoring.worst_set import gap_above, samples_to_separate, t_half_width

if TYPE_CHECKING:  # for the annotations only
    from admissable_jax.envs import MjxEnv
    from admissable_jax.policies import TrainedPolicy
    from admissable_jax.training import Trainer

MAX_AUDIT_EPISODES = 200_000  # sets × N stepped in one program; beyond it, audit fewer k or episodes
MAX_TELL_APART_EPISODES = 1000  # the most episodes per set tell_apart chooses
SEARCHES = ("exact", "beam")


@dataclasses.dataclass
class AuditConfig:
    run_dir: str = setting("", "a train run directory, an experiment pair's, or an experiment's folder (every pair, "
                               "then comparison.md of the modes); may be given first, without run_dir=")
    k: str = setting("1", "set sizes to audit, comma separated (e.g. 1,2)")
    episodes: int = setting(50, "N: deterministic episodes per set (the CI narrows as 1/sqrt(N))")
    out: str = setting("", "where the report goes (default RUN_DIR/audit-step<STEP>)")
    step: int = setting(-1, "the checkpoint (env step) to audit; -1 = the latest")
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
                              "(Stable-Baselines3, CleanRL, PyTorch) to audit on the Gymnasium env gym=")
    gym: str = setting("", "with policy=: the Gymnasium env id (Hopper-v5, or any other) the policy acts in")
    tell_apart: bool = setting(False, "audit twice: a pilot of `episodes` per set, then, from fresh start states, as "
                                      "many episodes per set as the pilot says tell the worst set of each k from the "
                                      "runner-up (80% power; at most 1000)")
    shapley: str = setting("0", "what each feature is worth: Shapley values of the return over the visible features; "
                                "exact (every coalition, d <= 20), or M random feature orders (exact where the 2^d "
                                "coalitions are fewer); 0 = none")


def _ks(text: str) -> tuple[int, ...]:
    try:
        ks = tuple(sorted({int(part) for part in text.split(",") if part.strip()}))
    except ValueError:
        raise ValueError(f"k must be a comma list of set sizes, e.g. 1,2; got {text!r}") from None
    if not ks or ks[0] < 1:
        raise ValueError(f"k must be a comma list of set sizes >= 1, got {text!r}")
    return ks


def check_audit_config(config: AuditConfig) -> None:
    if config.policy or config.gym:
        if config.run_dir or not (config.policy and config.gym):
            raise ValueError("a Python policy is audited with policy=MODULE:NAME and gym=ENV_ID, and no run directory")
        if config.score_estimator != "rollout" or config.search != "exact":
            raise ValueError("a Python policy is audited by rollouts of every set (it has no critic to estimate with)")
    elif not config.run_dir:
        raise ValueError("give the run directory: python -m admissable_jax.audit RUN_DIR [k=1,2] [episodes=50]")
    if config.steps and (config.step >= 0 or config.policy or is_experiment(config.run_dir)):
        raise ValueError("steps= audits several checkpoints of one run (a train run or one pair of an experiment), "
                         "without step= or policy=")
    _ks(config.k)
    if config.top < 1:
        raise ValueError(f"top must be at least 1, got {config.top}")
    if config.episodes < 2:
        raise ValueError("episodes must be at least 2 for a confidence interval")
    if config.slots < 0:
        raise ValueError(f"slots must be >= 0, got {config.slots}")
    if config.score_estimator not in SCORE_ESTIMATORS or config.score_horizon < 1:
        raise ValueError(f"score_estimator must be one of {', '.join(SCORE_ESTIMATORS)} and score_horizon >= 1")
    check_search(config.search, config.beam_width, config.ranker)
    _shapley(config.shapley)


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


def check_search(search: str, beam_width: int, ranker: str) -> None:
    if search not in SEARCHES:
        raise ValueError(f"search must be one of {', '.join(SEARCHES)}, got {search!r}")
    if beam_width < 1:
        raise ValueError(f"beam_width must be >= 1, got {beam_width}")
    if ranker not in SCORE_ESTIMATORS:
        raise ValueError(f"ranker must be one of {', '.join(SCORE_ESTIMATORS)}, got {ranker!r}")


@dataclasses.dataclass
class SetScore:
    """One audited set: its features, a_u, the 95% CI half-width, the drop from clean in %."""

    hidden: tuple[int, ...]
    names: tuple[str, ...]
    score: float
    ci95: float
    drop_percent: float
    returns: list[float]


@dataclasses.dataclass
class AuditResult:
    env: str
    estimator: str  # rollout: undiscounted returns; critic, horizon: discounted values (admissable_jax.scoring)
    n_episodes: int
    clean_score: float
    clean_ci95: float
    clean_returns: list[float]
    sets: dict[int, list[SetScore]]  # by k: every set in candidate_sets order, or a search's finalists
    feature_names: list[str]
    source: dict[str, Any]  # what was audited (run directory, step), for the report
    search: dict[int, dict[str, Any]] = dataclasses.field(default_factory=dict)  # by searched k: how, and ranks
    same_starts: bool = True  # every set's episode i starts from one state (False: a Gymnasium vector env's resets)
    shapley: ShapleyAttribution | None = None  # what each feature is worth, where asked (scoring.attribution)
    pilot: dict[str, Any] | None = None  # with tell_apart: the pilot audit that chose N (see audit)

    def worst(self, k: int, top: int) -> list[SetScore]:
        return sorted(self.sets[k], key=lambda entry: entry.score)[:top]

    def mean(self, k: int) -> float:
        """The mean a_u over all sets of size k: the average case (u drawn uniformly), where
        the paper warns a weak spot hides. NaN where k was searched (its finalists are the
        worst found, not all the sets)."""
        return float("nan") if k in self.search else float(np.mean([entry.score for entry in self.sets[k]]))

    def gaps_to_worst(self, k: int) -> list[GapToWorst]:
        """Every set of size k, worst first (its own gap 0), with how far its a_u lies above the worst's."""
        worst, *others = self.worst(k, len(self.sets[k]))
        return [GapToWorst(worst, 0.0, 0.0)] + [GapToWorst.between(worst, entry, self.same_starts) for entry in others]

    def episodes_to_separate(self, k: int) -> int | None:
        """N per set that would tell the worst set of size k from the runner-up (80% power at
        the gap and spread seen; :func:`~admissable_jax.scoring.worst_set.samples_to_separate`).
        None with one set, or where the two sets' returns do not differ."""
        if len(self.sets[k]) < 2:
            return None
        worst, runner_up = self.worst(k, 2)
        return samples_to_separate(worst.returns, runner_up.returns, self.same_starts)


@dataclasses.dataclass(frozen=True)
class GapToWorst:
    """A set's a_u above the worst's of its size, with the 95% interval's half-width
    (:func:`~admissable_jax.scoring.worst_set.gap_above`: paired where the sets share start
    states, else Welch's)."""

    entry: SetScore
    gap: float
    ci95: float

    @property
    def tied(self) -> bool:
        """Not told apart from the worst: the interval of the gap holds 0."""
        return self.gap - self.ci95 <= 0

    @classmethod
    def between(cls, worst: SetScore, entry: SetScore, paired: bool) -> GapToWorst:
        return cls(entry, *gap_above(worst.returns, entry.returns, paired))


def audit(env, policy_fn, params, ks=(1,), n_episodes: int = 50, seed: int = 0, num_slots: int | None = None,
          feature_names: list[str] | None = None, source: dict[str, Any] | None = None, estimator: str = "rollout",
          critic_fn=None, critic_params=None, horizon: int = 0, gamma: float = 0.99, search: str = "exact",
          beam_width: int = 4, ranker: str = "rollout", shapley: int | str = 0, progress: bool = False,
          tell_apart: bool = False) -> AuditResult:
    """Score every set of each size in ``ks`` and the clean case in one batch, N =
    ``n_episodes`` each from the same N start states, by
    :func:`~admissable_jax.scoring.score_missingness` with ``estimator`` (``critic`` and
    ``horizon`` from ``critic_fn`` and ``critic_params``; H = ``horizon``). With
    ``search="beam"`` the sets of each k > 1 are the ``beam_width`` finalists of a beam
    search ranked by ``ranker`` instead of all C(d, k). ``shapley`` (``"exact"``, or M >= 4
    feature orders; 0: none) adds the Shapley attribution's coalitions to the batch (module
    docstring). ``progress`` draws a bar over each rollout's episodes as they finish.

    ``tell_apart``: ``n_episodes`` is a pilot's N; the audit returned is a second one, from
    the start states of ``seed + 1``, with as many episodes per set as the pilot says would
    tell the worst set of each k from the runner-up (:meth:`AuditResult.episodes_to_separate`,
    the largest over the ks; at least the pilot's, at most MAX_TELL_APART_EPISODES and what
    one rollout may hold); its ``pilot`` says how N was chosen."""
    import jax

    from admissable_jax.scoring import beam_search_worst_sets, score_missingness

    check_search(search, beam_width, ranker)
    d = env.observation_size
    searched = [k for k in ks if search == "beam" and k > 1]
    plan = _shapley_plan(d, shapley, seed)
    check_audit_size(env.name, d, ks, n_episodes, search, beam_width, plan)
    if tell_apart:
        return _told_apart(functools.partial(
            audit, env, policy_fn, params, ks, num_slots=num_slots, feature_names=feature_names, source=source,
            estimator=estimator, critic_fn=critic_fn, critic_params=critic_params, horizon=horizon, gamma=gamma,
            search=search, beam_width=beam_width, ranker=ranker, progress=progress),
            ks, n_episodes, seed, shapley, _rollout_sets(d, ks, search, beam_width, plan))
    scorer = jax.jit(score_missingness, static_argnums=(0, 1, 5, 6, 7), static_argnames=(
        "score_estimator", "critic_fn", "score_horizon", "gamma", "progress"))
    key = jax.random.key(seed)

    def score(rows: np.ndarray, how: str):
        counted = progress and how == "rollout"  # the estimates run no episodes to count
        with _episode_bar((len(rows) + 1) * n_episodes) if counted else contextlib.nullcontext():
            scored = scorer(env, policy_fn, params, key, rows, n_episodes, None, num_slots, score_estimator=how,
                            critic_fn=critic_fn, critic_params=critic_params, score_horizon=horizon, gamma=gamma,
                            progress=_advance_episode_bar if counted else None)
            jax.effects_barrier()  # every report from inside the rollout made before the bar closes
        if bool(scored.capacity_exceeded):
            raise ValueError(f"the physics ran out of contact buffers: {env.capacity_message()}")
        return scored

    search_info, blocks = {}, []
    for k in ks:
        if k not in searched:
            blocks.append(candidate_sets(d, k))
            continue
        found = beam_search_worst_sets(lambda rows: score(rows, ranker).scores, d, k, beam_width)
        kept = np.asarray(found.found)
        finalists, ranker_scores = np.asarray(found.rows)[kept], np.asarray(found.scores)[kept]
        blocks.append(finalists)
        search_info[k] = {"method": "beam", "beam_width": beam_width, "ranker": ranker,
                          "sets_ranked": int(found.num_ranked), "sets_in_all": num_candidate_sets(d, k),
                          "ranker_scores": [[np.flatnonzero(row).tolist(), float(score_)]
                                            for row, score_ in zip(finalists, ranker_scores)]}
    return _audit_result(env.name, estimator, lambda rows: score(rows, estimator).returns, ks, blocks, plan,
                         feature_names or [str(i) for i in range(d)], source or {}, search_info)


def _told_apart(audit_with, ks, n_episodes: int, seed: int, shapley: int | str, rollout_sets: int) -> AuditResult:
    """``tell_apart``: a pilot audit (``audit_with(n_episodes=, seed=, shapley=)``) of
    ``n_episodes`` per set from ``seed``'s start states, without the Shapley coalitions;
    then the audit returned, from ``seed + 1``'s, with as many episodes per set as the pilot
    says tell the worst set of each k from the runner-up (the largest; at least the pilot's,
    at most MAX_TELL_APART_EPISODES and what one rollout of ``rollout_sets`` sets may hold)."""
    pilot = audit_with(n_episodes=n_episodes, seed=seed, shapley=0)
    needed = {k: pilot.episodes_to_separate(k) for k in ks}
    most = min(MAX_TELL_APART_EPISODES, MAX_AUDIT_EPISODES // (rollout_sets + 1))
    chosen = min(max([n_episodes] + [n for n in needed.values() if n is not None]), max(most, n_episodes))
    final = audit_with(n_episodes=chosen, seed=seed + 1, shapley=shapley)
    return dataclasses.replace(final, pilot={"episodes": n_episodes, "seed": seed, "needed": needed,
                                             "chosen": chosen, "most": most})


class _EpisodeBar:
    """A bar over a rollout's ``total`` episodes, drawn from the first report from inside the
    rollout on (so its clock and rate leave the compile out)."""

    def __init__(self, total: int):
        self.total, self.bar = total, None

    def advance(self, finished: int) -> None:
        if self.bar is None:
            self.bar = tqdm(total=self.total, unit="episode")
        self.bar.update(max(0, finished - self.bar.n))


_OPEN_EPISODE_BARS: list[_EpisodeBar] = []  # the bar the running rollout advances (innermost last)


@contextlib.contextmanager
def _episode_bar(total: int):
    """While open, :func:`_advance_episode_bar` advances a bar over ``total`` episodes."""
    bar = _EpisodeBar(total)
    _OPEN_EPISODE_BARS.append(bar)
    try:
        yield
    finally:
        _OPEN_EPISODE_BARS.remove(bar)
        if bar.bar is not None:
            bar.bar.close()


def _advance_episode_bar(finished) -> None:
    """Called from inside the jitted rollout with the episodes finished so far. One module
    function, not a bar's own method, so that the rollout compiles once for every audit
    (a new callable would be a new static argument)."""
    if _OPEN_EPISODE_BARS:
        _OPEN_EPISODE_BARS[-1].advance(int(finished))


def _shapley_plan(d: int, shapley: int | str, seed: int) -> ShapleyPlan | None:
    """The Shapley attribution's plan for ``shapley`` (``"exact"`` or M orders; 0: none)."""
    return plan_shapley(d, shapley, seed) if shapley else None


def _plan_size(plan: ShapleyPlan | None) -> int:
    return 0 if plan is None else len(plan.hidden_rows)


def _distinct_hidden_sets(blocks: list[np.ndarray], plan: ShapleyPlan | None) -> tuple[np.ndarray, np.ndarray]:
    """The distinct non-empty hidden sets of ``blocks`` and of ``plan`` (each valued once; the
    empty one is the clean case every rollout adds last), and where each row of the blocks,
    concatenated, lies among those rollout rows."""
    rows = np.concatenate(blocks + ([plan.hidden_rows] if plan is not None else []))
    distinct, index = np.unique(rows, axis=0, return_inverse=True)
    empty = ~distinct.any(axis=1)
    row_in_rollout = np.where(empty, (~empty).sum(), np.cumsum(~empty) - 1)  # the empty set: the clean row, last
    return distinct[~empty], row_in_rollout[index.reshape(-1)][:sum(len(block) for block in blocks)]


def _audit_result(env_name: str, estimator: str, score_rows, ks, blocks: list[np.ndarray], plan: ShapleyPlan | None,
                  names: list[str], source: dict[str, Any], search_info: dict[int, dict[str, Any]]) -> AuditResult:
    """The audit of one rollout by ``score_rows`` ((r, d) 0/1 rows -> (r + 1, N) returns,
    the clean case last) of the sets in ``blocks`` (one block of 0/1 rows per k in ``ks``)
    and of ``plan``'s coalitions, each distinct set once."""
    rollout_rows, block_rows = _distinct_hidden_sets(blocks, plan)
    valued = np.asarray(score_rows(rollout_rows), np.float64)
    returns = valued[np.append(block_rows, -1)]
    clean = returns[-1]
    clean_score = float(clean.mean())
    sets, row = {}, 0
    for k, block in zip(ks, blocks):
        entries = []
        for hidden_row in block:
            hidden = tuple(int(i) for i in np.flatnonzero(hidden_row))
            score_ = float(returns[row].mean())
            entries.append(SetScore(hidden, tuple(names[i] for i in hidden), score_, t_half_width(returns[row]),
                                    _drop(clean_score, score_), returns[row].tolist()))
            row += 1
        sets[k] = entries
    shapley = None if plan is None else shapley_attribution(
        plan, np.concatenate([rollout_rows, np.zeros((1, len(names)), np.float32)]), valued)
    return AuditResult(env_name, estimator, returns.shape[1], clean_score, t_half_width(clean), clean.tolist(), sets,
                       list(names), source, search_info, shapley=shapley)


def _gymnasium_features(env_id: str, ks, **env_kwargs) -> int:
    """d of the Gymnasium env ``env_id``; one-line ValueError if it cannot be made or a k
    in ``ks`` does not fit it."""
    import gymnasium

    from admissable_jax.envs import settotalmass_warning_dropped

    try:
        with settotalmass_warning_dropped():
            probe = gymnasium.make(env_id, **env_kwargs)
    except gymnasium.error.Error as error:
        raise ValueError(f"cannot make the Gymnasium env {env_id!r}: {error}") from None
    d = int(probe.observation_space.shape[0])
    probe.close()
    if not ks or any(not 1 <= k < d for k in ks):
        raise ValueError(f"ks must be set sizes 1 <= k < d = {d}, got {tuple(ks)}")
    return d


def audit_gymnasium(env_id: str, policy, ks=(1,), n_episodes: int = 50, num_envs: int = 8, seed: int = 0,
                    feature_names: list[str] | None = None, shapley: int | str = 0, progress: bool = False,
                    tell_apart: bool = False, **env_kwargs) -> AuditResult:
    """:func:`audit` for any policy on any Gymnasium env (Stable-Baselines3, CleanRL, your
    own PyTorch): every set of each size in ``ks`` and the clean case, N = ``n_episodes``
    episodes each, in one rollout on ``num_envs`` copies of ``gymnasium.make_vec(env_id)``
    by :func:`~admissable_jax.wrappers.score_policy` (``policy(masked_obs_batch) ->
    actions``). Episode starts follow the vector env's seed, so unlike :func:`audit` the
    sets do not share their N start states. ``feature_names`` default to our env's for
    Hopper-v5, Walker2d-v5, Ant-v5 and HalfCheetah-v5, else the indices. ``shapley``
    and ``tell_apart`` as in :func:`audit` (the gaps by Welch's t); ``progress`` draws a bar over
    the episodes. :func:`write_audit` writes the files."""
    from admissable_jax.envs import canonical_env_name, observation_names, settotalmass_warning_dropped
    from admissable_jax.wrappers import score_policy

    d = _gymnasium_features(env_id, ks, **env_kwargs)
    blocks = [candidate_sets(d, k) for k in ks]
    plan = _shapley_plan(d, shapley, seed)
    check_audit_size(env_id, d, ks, n_episodes, search=None, plan=plan)
    if tell_apart:
        return _told_apart(functools.partial(audit_gymnasium, env_id, policy, ks, num_envs=num_envs,
                                             feature_names=feature_names, progress=progress, **env_kwargs),
                           ks, n_episodes, seed, shapley, _rollout_sets(d, ks, None, 0, plan))
    if feature_names is None:
        try:
            feature_names = observation_names(canonical_env_name(env_id))
        except ValueError:  # not one of our envs
            feature_names = []
        if len(feature_names) != d:  # or made with other observation arguments
            feature_names = [str(i) for i in range(d)]

    def score_rows(rows: np.ndarray) -> np.ndarray:
        with settotalmass_warning_dropped():
            return score_policy(env_id, policy, n_episodes=n_episodes, num_envs=num_envs, seed=seed, hidden_sets=rows,
                                progress=progress, **env_kwargs).returns

    source = {"Gymnasium env": env_id, "policy": getattr(policy, "__name__", type(policy).__name__)}
    result = _audit_result(env_id, "rollout", score_rows, ks, blocks, plan, feature_names, source, {})
    return dataclasses.replace(result, same_starts=False)


def _drop(clean_score: float, score: float) -> float:
    """How far ``score`` lies below the clean return, in percent of it."""
    return 100.0 * (clean_score - score) / abs(clean_score) if clean_score else float("nan")


def check_audit_size(env_name: str, d: int, ks, n_episodes: int, search: str | None = "exact", beam_width: int = 4,
                     plan: ShapleyPlan | None = None) -> None:
    """Refuse, in one line, an audit whose one rollout would step more than
    MAX_AUDIT_EPISODES episodes: (its sets, where searched the b finalists, and the plan's
    coalitions, + the clean case) × N; a beam search's levels rank b · d sets a batch.
    ``search`` None: the audit cannot search (a Gymnasium policy's)."""
    num_sets = _rollout_sets(d, ks, search, beam_width, plan)
    if (num_sets + 1) * n_episodes > MAX_AUDIT_EPISODES:
        offers = ["lower episodes=", "drop the largest k"]
        offers += [] if search is None else ["use search=beam" if search == "exact" else "lower beam_width="]
        offers += [] if plan is None else ["give shapley= fewer feature orders"]
        raise ValueError(f"auditing k={','.join(map(str, ks))} on {env_name} is {num_sets:,} sets x {n_episodes} "
                         f"episodes in one rollout, over {MAX_AUDIT_EPISODES:,}: {', '.join(offers[:-1])} or {offers[-1]}")


def _rollout_sets(d: int, ks, search: str | None, beam_width: int, plan: ShapleyPlan | None) -> int:
    """The most sets an audit's one rollout scores besides the clean case: its sets (where
    searched, the b finalists) and the plan's coalitions; a beam search's level, b · d."""
    searched = [k for k in ks if search == "beam" and k > 1]
    num_sets = sum(beam_width if k in searched else num_candidate_sets(d, k) for k in ks) + _plan_size(plan)
    return max(num_sets, beam_width * d if searched else 0)


def write_audit(result: AuditResult, out: str, top: int = 10) -> list[str]:
    """report.md, audit.json and the figures into ``out``; returns the paths written."""
    os.makedirs(out, exist_ok=True)
    written = [os.path.join(out, "audit.json"), os.path.join(out, "report.md")]
    record = dataclasses.asdict(result)
    record["gaps_to_worst"] = {k: {"paired": result.same_starts, "episodes_to_separate": result.episodes_to_separate(k),
                                   "gaps": [{"hidden": list(gap.entry.hidden), "gap": gap.gap, "ci95": gap.ci95,
                                             "tied": gap.tied} for gap in result.gaps_to_worst(k)[1:]]}
                               for k in result.sets}
    with open(written[0], "w") as file:
        json.dump(record, file, indent=1)
    if 1 in result.sets:
        written.append(_bar_chart(result, os.path.join(out, "scores_k1.png")))
    if 2 in result.sets and 2 not in result.search:  # a search scores too few pairs for a map
        written.append(_pair_heatmap(result, os.path.join(out, "pairs_k2.png")))
    if result.shapley is not None:
        written.append(_shapley_chart(result, os.path.join(out, "shapley.png")))
    with open(written[1], "w") as file:
        file.write(_report(result, top, [os.path.basename(path) for path in written[2:]]))
    return written


def _report(result: AuditResult, top: int, figures: list[str]) -> str:
    source = ", ".join(f"{key} {value}" for key, value in result.source.items())
    episodes = ("deterministic episodes from the same N start states" if result.same_starts else
                "episodes of the policy as given, each set's from the vector env's own resets")
    measure = ("the mean undiscounted return of" if result.estimator == "rollout" else
               f"the `{result.estimator}` estimate (the critic's discounted value; admissable_jax.scoring) over")
    lines = [
        f"# Robustness audit: {result.env}", "",
        f"{source}. Every set u of the sizes below was hidden for whole episodes (hidden features read 0, "
        f"with the 0/1 indicator of the paper's masked observation); a_u is {measure} "
        f"N = {result.n_episodes} {episodes}, ± the 95% confidence "
        f"interval (Student's t); the drop is relative to the clean case.", "",
        f"**Clean return (nothing hidden): {result.clean_score:.1f} ± {result.clean_ci95:.1f}**", "",
    ]
    if result.pilot is not None:
        lines += [_pilot_sentence(result.pilot), ""]
    for k, entries in result.sets.items():
        worst = result.worst(k, top)
        searched = result.search.get(k)
        if searched:
            lines += [f"## k = {k}: the {len(worst)} worst found by beam search", "",
                      f"Beam search of width {searched['beam_width']} ranked {searched['sets_ranked']:,} candidate sets "
                      f"(of all {searched['sets_in_all']:,}) by `{searched['ranker']}`; its {len(entries)} finalists "
                      f"are scored here as every set above. A search may miss the worst set: "
                      f"`search=exact` scores them all.", ""]
        else:
            lines += [f"## k = {k}: the {len(worst)} worst of {len(entries)} sets", "",
                      f"Mean over all {len(entries)} sets (the average case, u drawn uniformly): "
                      f"{result.mean(k):.1f}, {_drop(result.clean_score, result.mean(k)):.1f}% below clean; "
                      f"the worst: {worst[0].score:.1f}.", ""]
        lines += ["| rank | hidden features | indices | a_u ± 95% CI | drop | above the worst ± 95% CI |",
                  "|---|---|---|---|---|---|"]
        for rank, gap in enumerate(result.gaps_to_worst(k)[:top], 1):
            entry = gap.entry
            lines.append(f"| {rank} | {', '.join(entry.names)} | {', '.join(map(str, entry.hidden))} | "
                         f"{entry.score:.1f} ± {entry.ci95:.1f} | {entry.drop_percent:.1f}% | "
                         f"{'—' if rank == 1 else f'+{_small(gap.gap)} ± {_small(gap.ci95)}'} |")
        lines += ["", _worst_told_apart(result, k), ""]
    if result.shapley is not None:
        lines += _shapley_section(result, result.shapley)
    lines += [f"![{name}]({name})" for name in figures]
    lines += ["", "Every number, with each episode's return: `audit.json`."]
    return "\n".join(lines) + "\n"


def _small(value: float) -> str:
    """One decimal, or two significant digits where one decimal would read 0.0 (a gap of
    0.004 ± 0.001 is told apart; "0.0 ± 0.0" would not say so)."""
    return f"{value:.1f}" if value == 0 or abs(value) >= 0.05 else f"{value:.2g}"


def _pilot_sentence(pilot: dict[str, Any]) -> str:
    """How ``tell_apart`` chose N, in words."""
    needed = ", ".join(f"k = {k}: {'—' if n is None else f'{n:,}'}" for k, n in pilot["needed"].items())
    largest = max([n for n in pilot["needed"].values() if n is not None], default=0)
    capped = (f" The largest, {largest:,}, is more than one audit here takes: capped at {pilot['chosen']:,}."
              if largest > pilot["chosen"] else "")
    return (f"N = {pilot['chosen']:,} was chosen by a pilot audit of {pilot['episodes']} episodes per set (the start "
            f"states of seed {pilot['seed']}; these are seed {pilot['seed'] + 1}'s): about this many episodes per set "
            f"would tell the worst set of each size from the runner-up ({needed}; —: the two did not differ), and "
            f"no fewer than the pilot's.{capped}")


def _worst_told_apart(result: AuditResult, k: int) -> str:
    """In words: is the worst set of size k told apart from the others, and if not, about
    how many episodes would tell it from the runner-up."""
    gaps = result.gaps_to_worst(k)
    if len(gaps) < 2:
        return "One set of this size: nothing to tell the worst apart from."
    how = ("paired episode by episode, as every set's episode i starts from one state" if result.same_starts
           else "Welch's t, as the sets' episodes start from different states")
    tied = [gap for gap in gaps[1:] if gap.tied]
    if not tied:
        return (f"The worst is told apart from every other set: the runner-up, {', '.join(gaps[1].entry.names)}, lies "
                f"{_small(gaps[1].gap)} ± {_small(gaps[1].ci95)} above it (the gap's 95% interval, {how}).")
    named = ", ".join("{" + ", ".join(gap.entry.names) + "}" for gap in tied[:5]) + (", ..." if len(tied) > 5 else "")
    needed = result.episodes_to_separate(k)
    more = ("the runner-up's returns equal the worst's episode by episode" if needed is None else
            f"about {needed:,} episodes per set would tell the worst from the runner-up at the gap and spread "
            f"seen (80% power; `episodes=`)")
    return (f"Not told apart from the worst (the gap's 95% interval holds 0; {how}; each set compared alone): "
            f"{len(tied)} of the other {len(gaps) - 1} sets ({named}). {more[0].upper()}{more[1:]}.")


def _shapley_order(attribution: ShapleyAttribution) -> list[int]:
    """Features by Shapley value, largest first."""
    return sorted(range(len(attribution.values)), key=lambda i: -attribution.values[i])


def _shapley_section(result: AuditResult, attribution: ShapleyAttribution) -> list[str]:
    """The report's table of every feature's Shapley value beside the loss of hiding it alone."""
    worth = attribution.full - attribution.blind
    how = (f"Exact: all {attribution.coalitions:,} coalitions valued" if attribution.method == "exact" else
           f"Estimated from M = {attribution.orders} random orders of the features in antithetic pairs "
           f"({attribution.coalitions:,} coalitions valued)")
    interval_orders = "" if attribution.method == "exact" else ", combined with that over the orders' pairs"
    value = "the mean return" if result.estimator == "rollout" else f"the `{result.estimator}` estimate"
    lines = ["## What each feature is worth: Shapley values", "",
             f"A coalition S of visible features is worth v(S), {value} with every other feature hidden. Feature i's "
             f"Shapley value φ_i is its share of what seeing everything is worth: v(all) = {attribution.full:.1f}, "
             f"v(none) = {attribution.blind:.1f}, and the φ_i sum to v(all) − v(none) = {worth:.1f}. Beside it, the "
             f"loss of hiding it alone (clean − a_i), which is all an adversary of k = 1 sees. A feature whose φ_i "
             f"is well above its loss alone carries what other features carry too: hidden alone it costs little, "
             f"hidden with them it costs much. {how}; ± the 95% interval over the N = {result.n_episodes} start "
             f"states (Student's t){interval_orders}. Method: admissable_jax.scoring.attribution.", "",
             "| rank | feature | index | φ_i ± 95% CI | share of v(all) − v(none) | loss hidden alone |",
             "|---|---|---|---|---|---|"]
    for rank, i in enumerate(_shapley_order(attribution), 1):
        share = 100 * attribution.values[i] / worth if worth else float("nan")
        lines.append(f"| {rank} | {result.feature_names[i]} | {i} | {attribution.values[i]:.1f} ± "
                     f"{attribution.ci95[i]:.1f} | {share:.1f}% | {attribution.leave_one_out[i]:.1f} |")
    return lines + [""]


def _shapley_chart(result: AuditResult, path: str, most: int = 30) -> str:
    """Horizontal bars of φ_i (95% CI), largest first, the loss of hiding each alone beside them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    attribution = result.shapley
    shown = _shapley_order(attribution)[:most]
    figure, ax = plt.subplots(figsize=(7, max(3, 0.3 * len(shown) + 1)))
    rows = np.arange(len(shown))
    ax.barh(rows, [attribution.values[i] for i in shown], xerr=attribution.ci95[shown], capsize=2,
            color="tab:blue", label="Shapley value φ_i (95% CI)")
    ax.scatter([attribution.leave_one_out[i] for i in shown], rows, marker="D", color="tab:red", zorder=3,
               label="loss when hidden alone (clean − $a_i$)")
    ax.axvline(0, color="black", linewidth=0.8)
    ax.set_yticks(rows, [result.feature_names[i] for i in shown], fontsize=7)
    ax.invert_yaxis()
    measure = "return" if result.estimator == "rollout" else f"{result.estimator} estimate"
    ax.set_xlabel(f"{measure}; the φ_i sum to v(all) − v(none) = {attribution.full - attribution.blind:.0f}")
    d = len(attribution.values)
    largest = f"the {len(shown)} largest of {d}" if len(shown) < d else "every feature"
    ax.set_title(f"{result.env}: what each feature is worth ({largest}; {attribution.method})", fontsize=9)
    ax.legend(fontsize=7)
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def _bar_chart(result: AuditResult, path: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    entries = result.sets[1]
    worst = min(range(len(entries)), key=lambda i: entries[i].score)
    figure, ax = plt.subplots(figsize=(max(6, 0.35 * len(entries)), 4))
    ax.bar(range(len(entries)), [e.score for e in entries], yerr=[e.ci95 for e in entries], capsize=2,
           color=["tab:red" if i == worst else "tab:blue" for i in range(len(entries))])
    ax.axhline(result.clean_score, color="black", linestyle="--", label=f"nothing hidden ({result.clean_score:.0f})")
    ax.axhline(result.mean(1), color="gray", linestyle=":", label=f"mean over the {len(entries)} sets ({result.mean(1):.0f})")
    ax.set_xticks(range(len(entries)), [", ".join(e.names) for e in entries], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(f"$a_u$: mean return of {result.n_episodes} episodes (95% CI)")
    ax.set_title(f"{result.env}: return with one feature hidden (worst in red)")
    ax.legend()
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def _pair_heatmap(result: AuditResult, path: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = len(result.feature_names)
    grid = np.full((d, d), np.nan)
    for entry in result.sets[2]:
        i, j = entry.hidden
        grid[i, j] = grid[j, i] = entry.score
    for entry in result.sets.get(1, []):  # the diagonal: the feature alone, where audited
        grid[entry.hidden[0], entry.hidden[0]] = entry.score
    size = max(5, 0.3 * d)
    figure, ax = plt.subplots(figsize=(size + 1.5, size))
    image = ax.imshow(grid, cmap="viridis")
    figure.colorbar(image, ax=ax, label="$a_{ij}$: mean return with features i and j hidden")
    labels = result.feature_names if d <= 40 else [str(i) for i in range(d)]
    ax.set_xticks(range(d), labels, rotation=90, fontsize=6)
    ax.set_yticks(range(d), labels, fontsize=6)
    ax.set_title(f"{result.env}: pairs hidden (diagonal: one feature, where audited)")
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def audit_python_policy(config: AuditConfig) -> tuple[AuditResult, list[str]]:
    """Audit ``config.policy`` (MODULE:NAME, importable from here) on the Gymnasium env
    ``config.gym`` by :func:`audit_gymnasium`; write the report into ``config.out`` (default
    ``audit-<ENV_ID>-<NAME>``)."""
    import importlib

    check_audit_config(config)
    module_name, _, name = config.policy.partition(":")
    if not module_name or not name:
        raise ValueError(f"policy must be MODULE:NAME (a callable in an importable module), got {config.policy!r}")
    try:
        policy = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"cannot load policy={config.policy}: {error}") from None
    if not callable(policy):
        raise ValueError(f"policy={config.policy} is a {type(policy).__name__}, not a callable masked_obs_batch -> actions")
    ks = _ks(config.k)
    _gymnasium_features(config.gym, ks)  # before anything is written
    out = config.out or f"audit-{config.gym}-{name}"
    make_directory(out, "audit folder")
    with reporting(f"auditing {config.policy} on {config.gym} for k={config.k} ({_episodes_asked(config)})"):
        result = audit_gymnasium(config.gym, policy, ks, config.episodes, num_envs=config.slots or 8, seed=config.seed,
                                 shapley=_shapley(config.shapley), progress=True, tell_apart=config.tell_apart)
    return result, write_audit(result, out, config.top)


def _episodes_asked(config: AuditConfig) -> str:
    return (f"a pilot of {config.episodes} episodes per set, then as many as tell the worst sets apart"
            if config.tell_apart else f"{config.episodes} episodes per set")


def audit_run(config: AuditConfig) -> tuple[AuditResult, list[str]]:
    """Audit the run in ``config.run_dir`` at ``config.step``; write the report."""
    check_audit_config(config)
    from admissable_jax.policies import load_policy

    policy = load_policy(config.run_dir, None if config.step < 0 else config.step)
    return _audit_policy(config, policy, _audit_env(config, policy), policy.trainer)


def _audit_env(config: AuditConfig, policy: TrainedPolicy) -> MjxEnv:
    """The run's env, sized for every episode the audit steps at once (at most ``slots``)."""
    from admissable_jax.envs import make_env

    train = policy.config
    return make_env(train.env, physics=train.physics, episode_length=train.episode_length,
                    max_batch=_slots(config, policy))


def _slots(config: AuditConfig, policy: TrainedPolicy) -> int:
    """Episodes stepped at once: all (sets + clean) × N, at most ``slots``, or as many as
    training's scoring steps (:func:`~admissable_jax.config.default_score_envs`: 32 on a CPU,
    where a batched step's cost grows with its batch; all on an accelerator), at most 4096."""
    from admissable_jax.config import default_score_envs

    d = policy.observation_size
    episodes = (sum(num_candidate_sets(d, k) for k in _ks(config.k)) + _plan_size(_plan(config, d)) + 1) * config.episodes
    return min(episodes, config.slots) if config.slots else min(default_score_envs(episodes), 4096)


def _plan(config: AuditConfig, d: int) -> ShapleyPlan | None:
    return _shapley_plan(d, _shapley(config.shapley), config.seed)


def _audit_policy(config: AuditConfig, policy: TrainedPolicy, env: MjxEnv,
                  trainer: Trainer) -> tuple[AuditResult, list[str]]:
    """Audit ``policy``'s networks with ``env`` and ``trainer``'s policy and critic functions
    (an experiment passes its first pair's to every pair, so the rollout compiles once)."""
    import jax

    from admissable_jax.envs import observation_names

    out = config.out or os.path.join(config.run_dir, f"audit-step{policy.step}")
    train = policy.config
    d = policy.observation_size
    check_audit_size(train.env, d, _ks(config.k), config.episodes, config.search, config.beam_width, _plan(config, d))
    make_directory(out, "audit folder")  # before the rollout, not after it
    with reporting(f"auditing checkpoint {policy.step} of {train.env} for k={config.k} ({config.search} search, "
                   f"{_episodes_asked(config)}, {env.physics_name} physics on {jax.default_backend()}; "
                   f"compiling included)"):
        result = audit(env, trainer.policy, policy.actor_params, _ks(config.k), config.episodes, config.seed,
                       _slots(config, policy), observation_names(train.env),
                       {"run": os.path.abspath(config.run_dir), "checkpoint (env step)": policy.step,
                        "mode": train.missingness, "seed": train.seed},
                       config.score_estimator, trainer.critic_values, policy.critic_params,
                       config.score_horizon, train.gamma, config.search, config.beam_width, config.ranker,
                       _shapley(config.shapley), progress=True, tell_apart=config.tell_apart)
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
    out = config.out or os.path.join(config.run_dir, "audit-over-training")
    results, written = _audit_each([(dataclasses.replace(config, out=os.path.join(out, f"step{step}")), step)
                                    for step in steps])
    written.append(_over_training_chart(results, os.path.join(out, "robustness_over_training.png")))
    written.append(os.path.join(out, "robustness_over_training.md"))
    with open(written[-1], "w") as file:
        file.write(_over_training_table(results) + "\n![worst and mean a_u per k by checkpoint]"
                   "(robustness_over_training.png)\n")
    return results, written


def _audit_each(jobs: list[tuple[AuditConfig, int | None]]) -> tuple[list[AuditResult], list[str]]:
    """Audit each (config, checkpoint step; None = the latest) of ``jobs`` into its folder,
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


def _over_training_table(results: list[AuditResult]) -> str:
    """Markdown: a row per checkpoint; per k the worst a_u (its set) and the mean a_u over the
    sets; with ``shapley=``, the feature worth most then and its φ."""
    first = results[0]
    ks = list(first.sets)
    attributed = all(result.shapley is not None for result in results)
    lines = [f"# Robustness over training: {first.env}, {first.source['run']}", "",
             f"Each checkpoint audited as its folder's report says ({_episodes_per_set(results)}, "
             f"`{first.estimator}`): per k, the worst a_u ± its 95% interval with its set, and the mean a_u over the "
             "sets (the average case; none for a searched k)" + ("; and the feature worth most, its Shapley value "
                                                                "φ_i of v(all) − v(none)" if attributed else "") + ".", "",
             "| env step | clean return | " + " | ".join(f"k={k}: worst a_u (set) | k={k}: mean a_u" for k in ks)
             + (" | worth most: φ_i of v(all) − v(none)" if attributed else "") + " |",
             "|---|---|" + "---|---|" * len(ks) + ("---|" if attributed else "")]
    for result in results:
        cells = []
        for k in ks:
            (worst,) = result.worst(k, 1)
            mean = result.mean(k)
            cells += [f"{worst.score:.1f} ± {worst.ci95:.1f} ({', '.join(worst.names)})",
                      "—" if math.isnan(mean) else f"{mean:.1f}"]
        if attributed:
            attribution, top = result.shapley, _shapley_order(result.shapley)[0]
            cells.append(f"{result.feature_names[top]}: {attribution.values[top]:.1f} ± {attribution.ci95[top]:.1f} "
                         f"of {attribution.full - attribution.blind:.1f}")
        lines.append(f"| {result.source['checkpoint (env step)']} | {result.clean_score:.1f} ± {result.clean_ci95:.1f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _over_training_chart(results: list[AuditResult], path: str) -> str:
    """Per k: the worst a_u (solid, with its 95% interval) and the mean a_u (dashed) by
    checkpoint; the clean return in black."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [result.source["checkpoint (env step)"] for result in results]
    figure, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(steps, [result.clean_score for result in results], "k--", marker="o", label="nothing hidden")
    for index, k in enumerate(results[0].sets):
        color = f"C{index}"
        worst = [result.worst(k, 1)[0] for result in results]
        ax.errorbar(steps, [entry.score for entry in worst], yerr=[entry.ci95 for entry in worst], color=color,
                    marker="o", capsize=3, label=f"k = {k}: worst $a_u$")
        means = [result.mean(k) for result in results]
        if not any(math.isnan(mean) for mean in means):
            ax.plot(steps, means, color=color, linestyle=":", marker=".", label=f"k = {k}: mean $a_u$ over the sets")
    ax.set_xlabel("checkpoint (env steps)")
    ax.set_ylabel(f"return ({results[0].n_episodes} episodes per set)")
    ax.set_title(f"{results[0].env}: robustness over training", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def is_experiment(path: str) -> bool:
    return os.path.isfile(os.path.join(path, "experiment.yaml"))


def audit_experiment(config: AuditConfig) -> tuple[list[AuditResult], list[str]]:
    """Audit every (seed, mode) pair of the experiment in ``config.run_dir`` at the same
    checkpoint, each into its own folder as :func:`audit_run` does (under ``out`` if given),
    then compare the modes in ``comparison.md``: per k, each pair's worst a_u and its mean
    a_u over the sets, mean ± 95% t-interval over seeds per mode, and adversarial − uniform
    on both with Welch's interval. It
    answers what the paper's Figure 1 cannot: does training against one missing feature
    also protect against two?"""
    check_audit_config(config)
    root = config.run_dir
    pairs = sorted(name for name in os.listdir(root) if os.path.isfile(os.path.join(root, name, "config.yaml")))
    if not pairs:
        raise FileNotFoundError(f"{root} holds an experiment.yaml but no pair directories")
    step = None if config.step < 0 else config.step
    pair_out = lambda name: os.path.join(config.out, name) if config.out else ""
    results, written = _audit_each([(dataclasses.replace(config, run_dir=os.path.join(root, name), out=pair_out(name)),
                                     step) for name in pairs])
    out = config.out or os.path.join(root, f"audit-step{results[0].source['checkpoint (env step)']}")
    make_directory(out, "audit folder")
    written.append(_comparison_chart(results, os.path.join(out, "comparison.png")))
    written.append(os.path.join(out, "comparison.md"))
    with open(written[-1], "w") as file:
        file.write(compare_modes(results) + "\n![worst a_u per k and mode](comparison.png)\n")
    return results, written


def _worst_by_mode(results: list[AuditResult]) -> dict[str, dict[int, np.ndarray]]:
    """Per mode and k: each pair's worst a_u (the lowest over the sets of that size)."""
    return _per_pair_by_mode(results, lambda result, k: min(entry.score for entry in result.sets[k]))


def _per_pair_by_mode(results: list[AuditResult], measure) -> dict[str, dict[int, np.ndarray]]:
    """Per mode and k: ``measure(result, k)`` of each pair, in pair order."""
    by_mode: dict[str, dict[int, list[float]]] = {}
    for result in results:
        for k in result.sets:
            by_mode.setdefault(result.source["mode"], {}).setdefault(k, []).append(measure(result, k))
    return {mode: {k: np.array(values) for k, values in per_k.items()} for mode, per_k in by_mode.items()}


def _comparison_chart(results: list[AuditResult], path: str) -> str:
    """Bars per k and mode: the mean of the pairs' worst a_u with its 95% t-interval, and
    each pair's own as a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from admissable_jax.plot import MODE_COLORS

    worst = _worst_by_mode(results)
    ks, modes = list(results[0].sets), sorted(worst)
    width = 0.8 / len(modes)
    figure, ax = plt.subplots(figsize=(max(5, 1.6 * len(ks) * len(modes)), 4))
    for offset, mode in enumerate(modes):
        x = np.arange(len(ks)) + (offset - (len(modes) - 1) / 2) * width
        bounds = [mean_and_interval(worst[mode][k][:, None]) for k in ks]
        means = np.array([mean[0] for mean, _, _ in bounds])
        errors = np.array([[mean[0] - low[0] for mean, low, _ in bounds], [high[0] - mean[0] for mean, _, high in bounds]])
        color = MODE_COLORS.get(mode, "black")
        ax.bar(x, means, width, yerr=errors, capsize=3, color=color, alpha=0.6,
               label=f"{mode} ({len(worst[mode][ks[0]])} seeds)")
        for position, k in zip(x, ks):
            ax.plot(np.full(len(worst[mode][k]), position), worst[mode][k], "o", color=color, markersize=3)
    ax.set_xticks(range(len(ks)), [f"k = {k}" for k in ks])
    ax.set_ylabel("worst $a_u$ over the sets of size k")
    ax.set_title(f"{results[0].env}, checkpoint {results[0].source['checkpoint (env step)']}: "
                 f"the worst hidden set per pair (bars: mean, 95% CI; dots: pairs)", fontsize=9)
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)
    return path


def compare_modes(results: list[AuditResult]) -> str:
    """Markdown: per k and mode, the pairs' worst a_u, their mean a_u over the sets (the
    average case; not for a searched k) and clean return (mean ± 95% t-interval over seeds)
    and the set most often worst; then adversarial − uniform per k on the worst and the mean
    (Welch's t: the seeds of one mode are independent of the other's), with the seeds per mode
    that would tell apart what these cannot (:func:`~admissable_jax.results.seeds_sentence`); where every pair
    was audited with ``shapley=``, each feature's Shapley value per mode."""
    by_mode: dict[str, list[AuditResult]] = {}
    for result in results:
        by_mode.setdefault(result.source["mode"], []).append(result)
    first = results[0]
    lines = [f"# Robustness audit of an experiment: {first.env}, checkpoint {first.source['checkpoint (env step)']}", "",
             f"Each pair audited as its own report says ({_episodes_per_set(results)}, `{first.estimator}`); "
             "here, per pair, the worst a_u over the sets of each size and the mean a_u over them (the average case, "
             "u drawn uniformly), then mean ± 95% t-interval over the seeds of a mode. Where a k was searched "
             "(`search=beam`), the worst found is an upper bound on the worst, and there is no mean.", "",
             "| k | mode | seeds | worst a_u | mean a_u over the sets | most often worst | clean return |",
             "|---|---|---|---|---|---|---|"]
    measures = {"worst a_u": _worst_by_mode(results), "mean a_u": _per_pair_by_mode(results, AuditResult.mean)}
    for k in first.sets:
        for mode, group in sorted(by_mode.items()):
            names = [", ".join(result.worst(k, 1)[0].names) for result in group]
            common = max(names, key=names.count)  # ties: the first pair's
            clean = np.array([result.clean_score for result in group])
            average = measures["mean a_u"][mode][k]
            lines.append(f"| {k} | {mode} | {len(group)} | {estimate(measures['worst a_u'][mode][k])} | "
                         f"{'—' if np.isnan(average).any() else estimate(average)} | {common} "
                         f"({names.count(common)} of {len(group)}) | {estimate(clean)} |")
    if {"adversarial", "uniform"} <= set(by_mode):
        lines += ["", "| k | measure | adversarial − uniform | 95% interval (Welch) | p (two-sided) | reading |",
                  "|---|---|---|---|---|---|"]
        compared = [(k, name, Difference(f"k={k} {name}", per_mode["adversarial"][k], per_mode["uniform"][k]))
                    for k in first.sets for name, per_mode in measures.items()
                    if not np.isnan(per_mode["adversarial"][k]).any()]
        lines += [f"| {k} | {name} | {difference.cells()} |" for k, name, difference in compared]
        sentence = seeds_sentence([(difference.metric, difference) for _, _, difference in compared])
        if sentence:
            lines += ["", sentence.rstrip()]
    if all(result.shapley is not None for result in results):
        lines += _shapley_by_mode(by_mode, first.feature_names)
    return "\n".join(lines) + "\n"


def _episodes_per_set(results: list[AuditResult]) -> str:
    """N of several audits (an experiment's pairs, a run's checkpoints): one number, or their
    range where ``tell_apart`` chose each."""
    low, high = min(result.n_episodes for result in results), max(result.n_episodes for result in results)
    return (f"N = {low} episodes per set" if low == high else
            f"N = {low}–{high} episodes per set, each audit's chosen by its pilot (`tell_apart`)")


def _shapley_by_mode(by_mode: dict[str, list[AuditResult]], names: list[str], most: int = 20) -> list[str]:
    """Markdown: each feature's Shapley value per mode, mean ± 95% t-interval over the
    mode's pairs; the ``most`` features of largest mean |φ_i| over every pair, largest φ first."""
    values = {mode: np.array([result.shapley.values for result in group]) for mode, group in sorted(by_mode.items())}
    overall = np.concatenate(list(values.values())).mean(axis=0)
    shown = sorted(sorted(range(len(names)), key=lambda i: -abs(overall[i]))[:most], key=lambda i: -overall[i])
    which = "every feature" if len(shown) == len(names) else f"the {len(shown)} of largest mean |φ_i| of {len(names)}"
    lines = ["", "## What each feature is worth, per mode", "",
             f"Each pair's Shapley values φ_i (its report's last section: the feature's share of v(all) − v(none)), "
             f"mean ± 95% t-interval over the seeds of a mode; {which}, largest mean first.", "",
             "| feature | index | " + " | ".join(values) + " |", "|---|---|" + "---|" * len(values)]
    for i in shown:
        lines.append(f"| {names[i]} | {i} | " + " | ".join(estimate(per_pair[:, i]) for per_pair in values.values()) + " |")
    return lines


def main(argv: list[str]) -> int:
    config = parse_args(AuditConfig, argv, "admissable_jax.audit",
                        "Which sensors break a policy? a_u of every set of k hidden features, with CIs, on one page.",
                        validate=check_audit_config, positional="run_dir")
    enable_compilation_cache()
    experiment = bool(config.run_dir) and is_experiment(config.run_dir)
    command = (audit_python_policy if config.policy else audit_over_training if config.steps
               else audit_experiment if experiment else audit_run)
    outcome, status = run_from_cli(command, config)
    if status:
        return status
    results, written = outcome if experiment or config.steps else ([outcome[0]], outcome[1])
    for result in results:
        pair = (f"{result.source['mode']} seed {result.source['seed']}: " if experiment else
                f"step {result.source['checkpoint (env step)']}: " if config.steps else "")
        if result.pilot is not None:
            print(f"{pair}N = {result.pilot['chosen']} episodes per set, chosen by a pilot of {result.pilot['episodes']}")
        for k in result.sets:
            (worst,) = result.worst(k, 1)
            average = "" if math.isnan(result.mean(k)) else f"; mean over the {len(result.sets[k])} sets {result.mean(k):.1f}"
            tied = sum(gap.tied for gap in result.gaps_to_worst(k)[1:])
            print(f"{pair}k={k}: worst {', '.join(worst.names)} ({list(worst.hidden)}): a_u {worst.score:.1f} ± "
                  f"{worst.ci95:.1f}, {worst.drop_percent:.1f}% below clean {result.clean_score:.1f}{average}; "
                  f"{f'not told apart from {tied} other set(s)' if tied else 'told apart from every other set'}")
        if result.shapley is not None:
            attribution, top = result.shapley, _shapley_order(result.shapley)[0]
            print(f"{pair}shapley: {result.feature_names[top]} ({top}) worth most: φ {attribution.values[top]:.1f} ± "
                  f"{attribution.ci95[top]:.1f} of v(all) − v(none) {attribution.full - attribution.blind:.1f}; "
                  f"hidden alone it costs {attribution.leave_one_out[top]:.1f} ({attribution.method})")
    if experiment or config.steps:
        with open(written[-1]) as file:
            print(file.read())
        each = "pair" if experiment else "checkpoint"
        print(f"wrote each {each}'s report, audit.json and figures into its audit folder, and {written[-1]}")
    else:
        print(f"wrote {', '.join(written)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
