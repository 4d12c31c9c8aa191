"""The audit itself: every set of k hidden features scored in one batched rollout (and the
clean case), N episodes each, ranked, each with its gap to the worst; for a JAX policy on
our envs (:func:`audit`) and for any policy on any Gymnasium env (:func:`audit_gymnasium`).
The package's docstring says what is measured and why."""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from typing import Any

import numpy as np

from admissable_jax.audit.watch import watched_rollout
from admissable_jax.cli import compiled_in_background
from admissable_jax.method import candidate_sets, check_fail_at
from admissable_jax.scoring import SCORE_ESTIMATORS
from admissable_jax.scoring.attribution import ShapleyAttribution, ShapleyPlan, plan_shapley, shapley_attribution
from admissable_jax.scoring.dropout import DropoutPlan, DropoutScore, dropout_scores
from admissable_jax.scoring.worst_set import gap_above, samples_to_separate, t_half_width



MAX_AUDIT_EPISODES = 200_000  # sets × N stepped in one program; beyond it, audit fewer k or episodes


MAX_TELL_APART_EPISODES = 1000  # the most episodes per set tell_apart chooses


SEARCHES = ("exact", "beam")


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
    """One audit: the clean case and every audited set of each size k, with what was audited and how."""

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
    dropout: list[DropoutScore] | None = None  # where asked: the return under random sensor failure (scoring.dropout)
    fail_at: int = 0  # the env step of each episode at which the hidden features failed (0: hidden from the start)
    clean_lengths: list[int] = dataclasses.field(default_factory=list)  # the clean episodes' env steps

    @property
    def ended_before_failing(self) -> int:
        """Clean episodes that ended by env step ``fail_at``: where every set's episode starts
        from the clean one's state, its sensors never failed in them (the policy saw everything
        until then, so it took the clean episode's course)."""
        return sum(length <= self.fail_at for length in self.clean_lengths) if self.fail_at else 0

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

    def worst_line(self, k: int) -> str:
        """What the audit found at size k in one line, as the command prints it: the worst set,
        its a_u ± 95% CI and drop below clean, the mean over the sets, and whether the worst
        is told apart from the others."""
        (worst,) = self.worst(k, 1)
        average = "" if math.isnan(self.mean(k)) else f"; mean over the {len(self.sets[k])} sets {self.mean(k):.1f}"
        tied = sum(gap.tied for gap in self.gaps_to_worst(k)[1:])
        return (f"k={k}: worst {', '.join(worst.names)} ({list(worst.hidden)}): a_u {worst.score:.1f} ± "
                f"{worst.ci95:.1f}, {worst.drop_percent:.1f}% below clean {self.clean_score:.1f}{average}; "
                f"{f'not told apart from {tied} other set(s)' if tied else 'told apart from every other set'}")

    def __repr__(self) -> str:
        """What was found, a line per k, not every episode's return (a notebook showing an
        audit of Hopper's 66 sets of 1 and 2 features printed each of their 50 returns)."""
        failing = f", hidden from env step {self.fail_at}" if self.fail_at else ""
        lines = [f"<AuditResult of {self.env}, {self.n_episodes} episodes per set{failing}: clean "
                 f"{self.clean_score:.1f} ± {self.clean_ci95:.1f}", *(f"  {self.worst_line(k)}" for k in self.sets)]
        return "\n".join(lines) + ">"


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
          tell_apart: bool = False, dropout: DropoutPlan | None = None, fail_at: int = 0) -> AuditResult:
    """Score every set of each size in ``ks`` and the clean case in one batch, N =
    ``n_episodes`` each from the same N start states, by
    :func:`~admissable_jax.scoring.score_missingness` with ``estimator`` (``critic`` and
    ``horizon`` from ``critic_fn`` and ``critic_params``; H = ``horizon``). With
    ``search="beam"`` the sets of each k > 1 are the ``beam_width`` finalists of a beam
    search ranked by ``ranker`` instead of all C(d, k). ``shapley`` (``"exact"``, or M >= 4
    feature orders; 0: none) adds the Shapley attribution's coalitions to the batch (module
    package docstring). ``dropout`` adds its masks to the batch: the expected return under
    random sensor failure (:mod:`admissable_jax.scoring.dropout`). ``fail_at`` > 0 (with the
    ``rollout`` estimator and ranker): every set's sensors fail at that env step of each
    episode, seen until then, instead of being hidden from its start. ``progress`` draws a bar
    over each rollout's episodes as they finish.

    ``tell_apart``: ``n_episodes`` is a pilot's N; the audit returned is a second one, from
    the start states of ``seed + 1``, with as many episodes per set as the pilot says would
    tell the worst set of each k from the runner-up (:meth:`AuditResult.episodes_to_separate`,
    the largest over the ks; at least the pilot's, at most MAX_TELL_APART_EPISODES and what
    one rollout may hold); its ``pilot`` says how N was chosen."""
    import jax

    from admissable_jax.scoring import beam_search_worst_sets, score_missingness
    from admissable_jax.scoring.estimators import rollout_in_segments

    check_search(search, beam_width, ranker)
    d = env.observation_size
    ks = audit_sizes(ks, d)
    searched = [k for k in ks if search == "beam" and k > 1]
    check_failing_audit(check_fail_at(fail_at, env.max_episode_steps), estimator, ranker if searched else "rollout")
    plan = shapley_plan(d, shapley, seed)
    check_audit_size(env.name, d, ks, n_episodes, search, beam_width, plan, dropout)
    if tell_apart:
        return _told_apart(functools.partial(
            audit, env, policy_fn, params, ks, num_slots=num_slots, feature_names=feature_names, source=source,
            estimator=estimator, critic_fn=critic_fn, critic_params=critic_params, horizon=horizon, gamma=gamma,
            search=search, beam_width=beam_width, ranker=ranker, progress=progress, fail_at=fail_at),
            ks, n_episodes, seed, shapley, dropout, rollout_sets(d, ks, search, beam_width, plan, dropout))
    scorer = jax.jit(score_missingness, static_argnums=(0, 1, 5, 6, 7), static_argnames=(
        "score_estimator", "critic_fn", "score_horizon", "gamma", "fail_at"))
    key = jax.random.key(seed)

    def score(rows: np.ndarray, how: str):
        # Compiled where a Ctrl-C is heard (audit.watch); called with the arguments not static.
        if how == "rollout":  # run from here in segments, its episodes counted by a bar
            rollout = rollout_in_segments(env, policy_fn, params, key, rows, n_episodes, None, num_slots,
                                          fail_at=fail_at, compile=compiled_in_background)
            scored = watched_rollout(lambda report: rollout(params, key, rows, report), (len(rows) + 1) * n_episodes,
                                     progress)
        else:  # the estimates run no episodes to count, and take seconds
            compiled = compiled_in_background(scorer.lower(
                env, policy_fn, params, key, rows, n_episodes, None, num_slots, score_estimator=how,
                critic_fn=critic_fn, critic_params=critic_params, score_horizon=horizon, gamma=gamma, fail_at=fail_at))
            scored = jax.block_until_ready(compiled(params, key, rows, critic_params=critic_params))
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
                          "sets_ranked": int(found.num_ranked), "sets_in_all": math.comb(d, k),
                          "ranker_scores": [[np.flatnonzero(row).tolist(), float(score_)]
                                            for row, score_ in zip(finalists, ranker_scores)]}
    result = _audit_result(env.name, estimator, lambda rows: score(rows, estimator), ks, blocks, plan,
                           feature_names or unnamed_features(d), source or {}, search_info, dropout)
    return dataclasses.replace(result, fail_at=fail_at)


def check_failing_audit(fail_at: int, estimator: str, ranker: str = "rollout") -> None:
    """ValueError in one line for sensors that fail mid-episode (``fail_at`` > 0) valued by an
    estimate: the critic values a start with u hidden from it, not a sensor that fails later."""
    estimates = [name for name, how in (("score_estimator", estimator), ("ranker", ranker)) if how != "rollout"]
    if fail_at and estimates:
        given = " and ".join(f"{name}=rollout" for name in estimates)
        raise ValueError(f"fail_at={fail_at} needs rollouts: give {given} (the critic values a start with u hidden "
                         f"from it, not a sensor that fails later)")


def _told_apart(audit_with, ks, n_episodes: int, seed: int, shapley: int | str, dropout: DropoutPlan | None,
                rollout_sets: int) -> AuditResult:
    """``tell_apart``: a pilot audit (``audit_with(n_episodes=, seed=, shapley=, dropout=)``) of
    ``n_episodes`` per set from ``seed``'s start states, without the Shapley coalitions and the dropout masks;
    then the audit returned, from ``seed + 1``'s, with as many episodes per set as the pilot
    says tell the worst set of each k from the runner-up (the largest; at least the pilot's,
    at most MAX_TELL_APART_EPISODES and what one rollout of ``rollout_sets`` sets may hold)."""
    pilot = audit_with(n_episodes=n_episodes, seed=seed, shapley=0, dropout=None)
    needed = {k: pilot.episodes_to_separate(k) for k in ks}
    most = min(MAX_TELL_APART_EPISODES, MAX_AUDIT_EPISODES // (rollout_sets + 1))
    chosen = min(max([n_episodes] + [n for n in needed.values() if n is not None]), max(most, n_episodes))
    final = audit_with(n_episodes=chosen, seed=seed + 1, shapley=shapley, dropout=dropout)
    return dataclasses.replace(final, pilot={"episodes": n_episodes, "seed": seed, "needed": needed,
                                             "chosen": chosen, "most": most})


def shapley_plan(d: int, shapley: int | str, seed: int) -> ShapleyPlan | None:
    """The Shapley attribution's plan for ``shapley`` (``"exact"`` or M orders; 0: none)."""
    return plan_shapley(d, shapley, seed) if shapley else None


def plan_size(plan: ShapleyPlan | None) -> int:
    return 0 if plan is None else len(plan.hidden_rows)


def _distinct_hidden_sets(row_blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The distinct non-empty hidden sets of ``row_blocks`` (each valued once; the empty one
    is the clean case every rollout adds last), and where each of their rows, concatenated,
    lies among those rollout rows."""
    rows = np.concatenate(row_blocks)
    distinct, index = np.unique(rows, axis=0, return_inverse=True)
    empty = ~distinct.any(axis=1)
    row_in_rollout = np.where(empty, (~empty).sum(), np.cumsum(~empty) - 1)  # the empty set: the clean row, last
    return distinct[~empty], row_in_rollout[index.reshape(-1)]


def _audit_result(env_name: str, estimator: str, score_rows, ks, blocks: list[np.ndarray], plan: ShapleyPlan | None,
                  names: list[str], source: dict[str, Any], search_info: dict[int, dict[str, Any]],
                  dropout: DropoutPlan | None = None) -> AuditResult:
    """The audit of one rollout by ``score_rows`` ((r, d) 0/1 rows -> the scores, whose
    ``returns`` and ``lengths`` are (r + 1, N), the clean case last) of the sets in ``blocks``
    (one block of 0/1 rows per k in ``ks``), of ``dropout``'s masks and of ``plan``'s
    coalitions, each distinct set once."""
    num_sets = sum(len(block) for block in blocks)
    masks = [] if dropout is None else [dropout.hidden_rows]
    rollout_rows, row_index = _distinct_hidden_sets(blocks + masks + ([plan.hidden_rows] if plan is not None else []))
    scored = score_rows(rollout_rows)
    valued = np.asarray(scored.returns, np.float64)
    returns = valued[np.append(row_index[:num_sets], -1)]
    clean = returns[-1]
    clean_score = float(clean.mean())
    sets, row = {}, 0
    for k, block in zip(ks, blocks):
        entries = []
        for hidden_row in block:
            hidden = tuple(int(i) for i in np.flatnonzero(hidden_row))
            score_ = float(returns[row].mean())
            entries.append(SetScore(hidden, tuple(names[i] for i in hidden), score_, t_half_width(returns[row]),
                                    drop_below_clean(clean_score, score_), returns[row].tolist()))
            row += 1
        sets[k] = entries
    shapley = None if plan is None else shapley_attribution(
        plan, np.concatenate([rollout_rows, np.zeros((1, len(names)), np.float32)]), valued)
    failures = None if dropout is None else dropout_scores(
        dropout, valued[row_index[num_sets:num_sets + len(dropout.hidden_rows)]].mean(axis=1))
    return AuditResult(env_name, estimator, returns.shape[1], clean_score, t_half_width(clean), clean.tolist(), sets,
                       list(names), source, search_info, shapley=shapley, dropout=failures,
                       clean_lengths=np.asarray(scored.lengths)[-1].tolist())


def unnamed_features(d: int) -> list[str]:
    """Names for an observation of ``d`` entries that names none (a Gymnasium env other than
    ours): ``feature 0``, ..., so that a report reads "worst feature 3", not "worst 3"."""
    return [f"feature {i}" for i in range(d)]


def gymnasium_features(env_id: str, **env_kwargs) -> int:
    """d of the Gymnasium env ``env_id``; one-line ValueError if it cannot be made."""
    import gymnasium

    from admissable_jax.envs import settotalmass_warning_dropped

    try:
        with settotalmass_warning_dropped():
            probe = gymnasium.make(env_id, **env_kwargs)
    except gymnasium.error.Error as error:
        raise ValueError(f"cannot make the Gymnasium env {env_id!r}: {error}") from None
    d = int(probe.observation_space.shape[0])
    probe.close()
    return d


def audit_sizes(ks, d: int) -> tuple[int, ...]:
    """The set sizes an audit scores: ``ks`` (several, or one int), each once, smallest
    first, as ``audit k=`` reads them; TypeError/ValueError in one line for a size that is
    no int, or not 1 <= k < d."""
    sizes = (ks,) if isinstance(ks, numbers.Integral) else tuple(ks)
    if not all(isinstance(k, numbers.Integral) and not isinstance(k, bool) for k in sizes):
        raise TypeError(f"ks must be set sizes (ints), got {ks!r}")
    if not sizes or any(not 1 <= k < d for k in sizes):
        raise ValueError(f"k must be set sizes 1 <= k < d = {d}, got {', '.join(map(str, sizes)) or 'none'}")
    return tuple(sorted({int(k) for k in sizes}))


def audit_gymnasium(env_id: str, policy, ks=(1,), n_episodes: int = 50, num_envs: int = 8, seed: int = 0,
                    feature_names: list[str] | None = None, shapley: int | str = 0, progress: bool = False,
                    tell_apart: bool = False, dropout: DropoutPlan | None = None, fail_at: int = 0,
                    **env_kwargs) -> AuditResult:
    """:func:`audit` for any policy on any Gymnasium env (Stable-Baselines3, CleanRL, your
    own PyTorch): every set of each size in ``ks`` and the clean case, N = ``n_episodes``
    episodes each, in one rollout on ``num_envs`` copies of ``gymnasium.make_vec(env_id)``
    by :func:`~admissable_jax.wrappers.score_policy` (``policy(masked_obs_batch) ->
    actions``). Episode starts follow the vector env's seed, so unlike :func:`audit` the
    sets do not share their N start states. ``feature_names`` default to our env's for
    Hopper-v5, Walker2d-v5, Ant-v5 and HalfCheetah-v5, else the indices. ``shapley``,
    ``dropout``, ``fail_at`` and ``tell_apart`` as in :func:`audit` (the gaps by Welch's t); ``progress`` draws a
    bar over
    the episodes. :func:`~admissable_jax.audit.report.write_audit` writes the files."""
    from admissable_jax.envs import canonical_env_name, observation_names, settotalmass_warning_dropped
    from admissable_jax.wrappers import PolicyScores, score_policy

    d = gymnasium_features(env_id, **env_kwargs)
    ks = audit_sizes(ks, d)
    check_fail_at(fail_at)
    blocks = [candidate_sets(d, k) for k in ks]
    plan = shapley_plan(d, shapley, seed)
    check_audit_size(env_id, d, ks, n_episodes, search=None, plan=plan, dropout=dropout)
    if tell_apart:
        return _told_apart(functools.partial(audit_gymnasium, env_id, policy, ks, num_envs=num_envs,
                                             feature_names=feature_names, progress=progress, fail_at=fail_at,
                                             **env_kwargs),
                           ks, n_episodes, seed, shapley, dropout, rollout_sets(d, ks, None, 0, plan, dropout))
    if feature_names is None:
        try:
            feature_names = observation_names(canonical_env_name(env_id))
        except ValueError:  # not one of our envs
            feature_names = []
        if len(feature_names) != d:  # or made with other observation arguments
            feature_names = unnamed_features(d)

    def score_rows(rows: np.ndarray) -> PolicyScores:
        with settotalmass_warning_dropped():
            return score_policy(env_id, policy, n_episodes=n_episodes, num_envs=num_envs, seed=seed, hidden_sets=rows,
                                progress=progress, fail_at=fail_at, **env_kwargs)

    source = {"Gymnasium env": env_id, "policy": getattr(policy, "__name__", type(policy).__name__)}
    result = _audit_result(env_id, "rollout", score_rows, ks, blocks, plan, feature_names, source, {}, dropout)
    return dataclasses.replace(result, same_starts=False, fail_at=fail_at)


def drop_below_clean(clean_score: float, score: float) -> float:
    """How far ``score`` lies below the clean return, in percent of it."""
    return 100.0 * (clean_score - score) / abs(clean_score) if clean_score else float("nan")


def check_audit_size(env_name: str, d: int, ks, n_episodes: int, search: str | None = "exact", beam_width: int = 4,
                     plan: ShapleyPlan | None = None, dropout: DropoutPlan | None = None) -> None:
    """Refuse, in one line, an audit whose one rollout would step more than
    MAX_AUDIT_EPISODES episodes: (its sets, where searched the b finalists, the plan's
    coalitions and the dropout masks, + the clean case) × N; a beam search's levels rank
    b · d sets a batch. ``search`` None: the audit cannot search (a Gymnasium policy's)."""
    num_sets = rollout_sets(d, ks, search, beam_width, plan, dropout)
    if (num_sets + 1) * n_episodes > MAX_AUDIT_EPISODES:
        offers = ["lower episodes=", "drop the largest k"]
        offers += [] if search is None else ["use search=beam" if search == "exact" else "lower beam_width="]
        offers += [] if plan is None else ["give shapley= fewer feature orders"]
        offers += [] if dropout is None else ["give dropout= fewer rates or dropout_masks= fewer masks"]
        raise ValueError(f"auditing k={','.join(map(str, ks))} on {env_name} is {num_sets:,} sets x {n_episodes} "
                         f"episodes in one rollout, over {MAX_AUDIT_EPISODES:,}: {', '.join(offers[:-1])} or {offers[-1]}")


def rollout_sets(d: int, ks, search: str | None, beam_width: int, plan: ShapleyPlan | None,
                 dropout: DropoutPlan | None = None) -> int:
    """The most sets an audit's one rollout scores besides the clean case: its sets (where
    searched, the b finalists), the plan's coalitions and the dropout masks; a beam search's
    level, b · d.
    Counted, never listed: a searched k may have far more sets than can be listed
    (MAX_CANDIDATE_SETS; Ant at k = 3: 187,460), and an exact one is refused by its count."""
    searched = [k for k in ks if search == "beam" and k > 1]
    masks = 0 if dropout is None else len(dropout.hidden_rows)
    num_sets = sum(beam_width if k in searched else math.comb(d, k) for k in ks) + plan_size(plan) + masks
    return max(num_sets, beam_width * d if searched else 0)
