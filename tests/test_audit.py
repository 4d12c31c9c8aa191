"""Score estimators beyond the paper's rollout (critic, horizon) and the robustness audit.

All on the pure-JAX point mass (seconds to compile), with hand-computed expectations: a
critic that is a known function, horizons of one and two steps, and the audit's report
against its JSON and against ``score_missingness``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import pathlib
import re
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax import TrainConfig, candidate_sets, make_env, mask_observation, score_missingness, train_fn
from admissable_jax.audit import audit, main as audit_main
from admissable_jax.exported_policy import ExportedPolicy
from admissable_jax.policies import load_policy
from admissable_jax.config import curve_mode
from admissable_jax.results import estimate
from admissable_jax.scoring import beam_search_worst_sets, estimate_scores
from admissable_jax.scoring.estimators import rollout_in_segments
from admissable_jax.scoring.rollout_scores import SEGMENT_LOOP_STEPS
from admissable_jax.scoring.set_search import first_copies
from admissable_jax.scoring.attribution import ShapleyPlan, plan_shapley, shapley_attribution
from admissable_jax.scoring.dropout import plan_dropout
from admissable_jax.scoring.worst_set import samples_to_separate

ENV = make_env("point_mass", episode_length=12)
SETS = jnp.asarray(candidate_sets(4, k=1))
N = 3


def steer(params, masked_obs):
    """A hand-written controller of the masked observation: push towards the origin."""
    return jnp.clip(-params * masked_obs[:2] - 0.5 * masked_obs[2:4], -1, 1)


def known_critic(params, masked_obs, action):
    """Twin Q as a known function: sum of the masked observation and the action, and 1 more."""
    q = masked_obs.sum() + action.sum()
    return jnp.stack([q, q + 1.0])


def test_critic_and_horizon_estimates_by_hand():
    """â_u = Σ_{t<H} γ^t r_t + γ^H · alive_H · min(Q1, Q2) at H = 0, 1 and 2, stepped by hand
    (H = 2 is the first where an undiscounted sum of rewards differs)."""
    rng = jax.random.key(3)
    starts = jax.vmap(ENV.reset)(jax.random.split(rng, N))
    rows = jnp.concatenate([SETS, jnp.zeros((1, 4))])  # every set, then the clean case
    gain, gamma = jnp.asarray(0.8), 0.9

    def by_hand(start, hidden, horizon):
        state, discounted, alive = start, 0.0, True
        for t in range(horizon):
            if alive:
                state = ENV.step(state, steer(gain, mask_observation(state.obs, hidden)))
                discounted += gamma**t * float(state.reward)
                alive = not bool(state.terminated) and int(state.step_count) < ENV.max_episode_steps
        masked = mask_observation(state.obs, hidden)
        return discounted + gamma**horizon * alive * float(masked.sum() + steer(gain, masked).sum())  # min of the twins

    for horizon in (0, 1, 2):
        estimates = estimate_scores(ENV, steer, gain, known_critic, None, rng, SETS, N, horizon=horizon, gamma=gamma)
        for row_index, hidden in enumerate(rows):
            expected = [by_hand(jax.tree.map(lambda x: x[i], starts), hidden, horizon) for i in range(N)]
            np.testing.assert_allclose(estimates.returns[row_index], expected, rtol=1e-5)
        np.testing.assert_allclose(estimates.scores, estimates.returns[:-1].mean(1), rtol=1e-6)
        np.testing.assert_allclose(estimates.clean_score, estimates.returns[-1].mean(), rtol=1e-6)
        assert int(estimates.loop_steps) == horizon


def test_full_horizon_without_discount_is_the_papers_rollout():
    """γ = 1 and H = the episode limit: no bootstrap is left, and each episode's estimate is
    its undiscounted return from the start state rollout scoring uses for it."""
    rng, gain = jax.random.key(5), jnp.asarray(0.8)
    rollout = score_missingness(ENV, steer, gain, rng, SETS, N)
    full = estimate_scores(ENV, steer, gain, known_critic, None, rng, SETS, N, horizon=ENV.max_episode_steps, gamma=1.0)
    np.testing.assert_allclose(full.returns, rollout.returns, rtol=1e-5)
    np.testing.assert_array_equal(full.lengths, rollout.lengths)
    with pytest.raises(ValueError, match="horizon must be >= 0"):
        estimate_scores(ENV, steer, gain, known_critic, None, rng, SETS, N, horizon=-1)
    # score_missingness, the public entry, names what is wrong with its arguments in one line.
    for sets, n_episodes, message in ((SETS[:, :2], N, r"hidden_sets must be \(\|U\|, d = 4\) 0/1 rows, one per set, "
                                                       r"got shape \(4, 2\)"),
                                      (2 * SETS, N, r"hidden_sets must hold only 0 \(seen\) and 1 \(hidden\)"),
                                      (SETS, 0, "n_episodes must be an int >= 1, got 0")):
        with pytest.raises(ValueError, match=message):
            score_missingness(ENV, steer, gain, rng, sets, n_episodes)
    # ...and a policy whose action is not one of the env's, found by tracing it (nothing runs).
    with pytest.raises(ValueError, match=r"policy_fn\(params, masked_obs\) must return one action of shape \(2,\) "
                                         r"for a masked observation of shape \(8,\), got \(3,\)"):
        score_missingness(ENV, lambda gain, masked: jnp.zeros(3), gain, rng, SETS, N)
    # ...and a seed given where the key goes, or a batch of keys.
    for key, given in ((0, "int 0"), (jax.random.split(rng, 3), r"an array of .* and shape \(3,")):
        with pytest.raises(TypeError, match=rf"rng must be one JAX PRNG key \(jax.random.key\(seed\)\), got {given}"):
            score_missingness(ENV, steer, gain, key, SETS, N)
    with pytest.raises(TypeError, match=r"^env must be an env, as make_env builds it, got 'point_mass': "
                                        r"make_env\('point_mass'\)$"):
        score_missingness("point_mass", steer, gain, rng, SETS, N)  # (it said "'str' object has no attribute ...")
    np.testing.assert_array_equal(score_missingness(ENV, steer, gain, rng, SETS, np.int64(N)).scores, rollout.scores)
    # With progress=, run from the host in segments of SEGMENT_LOOP_STEPS loop steps, by
    # programs without host callbacks: the same episodes, the episodes finished told after
    # each segment; inside a caller's jit, refused in one line.
    reports, lowered = [], []
    in_segments = rollout_in_segments(ENV, steer, gain, rng, SETS, N, num_slots=3,
                                      compile=lambda program: lowered.append(program.as_text()) or program.compile())
    assert len(lowered) == 3 and not [text for text in lowered if "callback" in text]  # so JAX's disk cache keeps them
    segmented = in_segments(gain, rng, SETS, reports.append)
    in_one = score_missingness(ENV, steer, gain, rng, SETS, N, num_slots=3)
    np.testing.assert_allclose(segmented.returns, in_one.returns, rtol=1e-6)
    np.testing.assert_array_equal(segmented.lengths, in_one.lengths)
    assert int(segmented.loop_steps) == int(in_one.loop_steps) > 2 * SEGMENT_LOOP_STEPS
    assert len(reports) == -(-int(in_one.loop_steps) // SEGMENT_LOOP_STEPS)
    assert reports == sorted(reports) and 0 < reports[0] and reports[-1] == (len(SETS) + 1) * N
    quiet = score_missingness(ENV, steer, gain, rng, SETS, N, num_slots=3, progress=lambda finished: None)
    assert quiet.scores.tolist() == segmented.scores.tolist()
    with pytest.raises(ValueError, match=r"^score_missingness with progress= runs its rollout from the host, in "
                                         r"segments: call it outside jit \(or without progress=\)"):
        jax.jit(lambda gain: score_missingness(ENV, steer, gain, rng, SETS, N, progress=print).scores)(gain)
    # Sensors that fail at env step 4: each episode stepped by hand from the rollout's own start
    # states, its first 4 actions seeing everything, the rest with u hidden.
    failing = score_missingness(ENV, steer, gain, rng, SETS, N, fail_at=4)
    starts = jax.vmap(ENV.reset)(jax.random.split(rng, N))
    for row_index, hidden in enumerate(SETS):
        for i in range(N):
            state, total = jax.tree.map(lambda x: x[i], starts), 0.0
            while True:
                seen = hidden * (int(state.step_count) >= 4)
                state = ENV.step(state, steer(gain, mask_observation(state.obs, seen)))
                total += float(state.reward)
                if bool(state.terminated) or int(state.step_count) >= ENV.max_episode_steps:
                    break
            assert float(failing.returns[row_index, i]) == pytest.approx(total, rel=1e-5, abs=1e-5)
    assert not np.allclose(failing.scores, rollout.scores)  # (a failure at step 4 is not one from the start)
    np.testing.assert_array_equal(failing.returns[-1], rollout.returns[-1])  # nothing fails in the clean case
    # Several failure steps split each set's N = 3 episodes: episode i fails at the i-th step,
    # from its own start state, so each is the episode of the same start with that step alone.
    late = score_missingness(ENV, steer, gain, rng, SETS, N, fail_at=8)
    spread = score_missingness(ENV, steer, gain, rng, SETS, N, fail_at="8,0,4")
    for i, alone in enumerate((rollout, failing, late)):
        np.testing.assert_allclose(spread.returns[:, i], alone.returns[:, i], rtol=1e-6)
    np.testing.assert_allclose(spread.scores, spread.returns[:-1].mean(axis=1), rtol=1e-6)
    assert not any(np.allclose(spread.scores, alone.scores) for alone in (rollout, failing, late))  # (a mix of all three)
    for fail_at, estimator, message in ((12, "rollout", "fail_at=12 is not below the episodes' 12 steps"),
                                        (-1, "rollout", r"fail_at must be an env step >= 0 \(0: hidden from the start\)"),
                                        (4, "critic", "fail_at=4 needs score_estimator=rollout"),
                                        ([8, 0, 4], "critic", "fail_at=0,4,8 needs score_estimator=rollout"),
                                        ((0, 4), "rollout", "fail_at=0,4 splits each set's n_episodes=3 episodes "
                                                            "unevenly: give n_episodes a multiple of 2")):
        with pytest.raises(ValueError, match=message):
            score_missingness(ENV, steer, gain, rng, SETS, N, fail_at=fail_at, score_estimator=estimator,
                              critic_fn=known_critic)


def test_beam_search_finds_the_known_worst_pair():
    """The steering controller needs both positions: hiding x and y leaves only damping, the
    worst pair of all C(4, 2) = 6 (checked exactly here). Greedy and width-2 beam search find
    it from the single features up, with its exact score."""
    rng, gain = jax.random.key(7), jnp.asarray(0.8)

    def rollout_scores(rows):
        return score_missingness(ENV, steer, gain, rng, jnp.asarray(rows), 8).scores

    exact = np.asarray(rollout_scores(candidate_sets(4, k=2)))
    pairs = [tuple(np.flatnonzero(row)) for row in candidate_sets(4, k=2)]
    assert pairs[int(np.argmin(exact))] == (0, 1)
    search = jax.jit(beam_search_worst_sets, static_argnums=(0, 1, 2, 3))  # it runs under jit, as in training
    for width in (1, 2):
        found = search(rollout_scores, 4, 2, width)
        assert found.found.all() and tuple(np.flatnonzero(found.rows[0])) == (0, 1)
        assert float(found.scores[0]) == pytest.approx(float(exact.min()), rel=1e-5)
        # 4 singles, then each kept single's 3 extensions, the pair both share ranked once.
        assert int(found.num_ranked) == 4 + 3 * width - (width - 1)
    # Width 3 on d = 3, k = 3: one set of 3 exists; the other two beam slots stay empty.
    few = beam_search_worst_sets(lambda rows: -rows.sum(axis=1), 3, 3, 3)
    np.testing.assert_array_equal(few.found, [True, False, False])
    np.testing.assert_array_equal(few.rows[0], [1, 1, 1])
    # A level keeps the first copy of each set among its new candidates, features packed 32
    # to a word: here d = 70, three words, sets that differ in the second or third word only.
    sets = [(1, 40), (1, 69), (1, 40), (40, 69), (1, 69), (64,), (65,), (1, 40)]
    rows = np.zeros((len(sets), 70), np.float32)
    for row, hidden in zip(rows, sets):
        row[list(hidden)] = 1
    among = np.array([1, 1, 1, 0, 1, 1, 1, 1], bool)
    np.testing.assert_array_equal(first_copies(rows, among), [1, 1, 0, 0, 0, 1, 1, 0])
    with pytest.raises(ValueError, match="need 1 <= k <= d = 4"):
        beam_search_worst_sets(rollout_scores, 4, k=5)

    # The audit's search=beam: the same finalists, confirmed by a rollout from the same N
    # start states (so with the exact scores); k = 1 stays exact.
    result = audit(ENV, steer, gain, ks=(1, 2), n_episodes=8, seed=7, search="beam", beam_width=2)
    assert [entry.hidden for entry in result.sets[1]] == [(0,), (1,), (2,), (3,)]
    assert len(result.sets[2]) == 2 and result.worst(2, 1)[0].hidden == (0, 1)
    assert result.worst(2, 1)[0].score == pytest.approx(float(exact.min()), rel=1e-5)
    assert result.search[2]["ranker"] == "rollout" and 4 < result.search[2]["sets_ranked"] <= 4 + 2 * 3
    # The average case over the exact k = 1 sets; none over a searched k's finalists.
    assert result.mean(1) == pytest.approx(float(np.mean(rollout_scores(candidate_sets(4, k=1)))), rel=1e-5)
    assert math.isnan(result.mean(2))
    with pytest.raises(ValueError, match="score_estimator=critic needs the critic"):
        audit(ENV, steer, gain, ks=(2,), n_episodes=2, search="beam", ranker="critic")


def max_of_visible(masked_obs: np.ndarray) -> np.ndarray:
    """On ConstantFeatures (observes 1, 2, 3), acts with 1 + the largest value it sees: earns 5 · that
    (5 blind: v(none) is not 0, so a share of v(all) − v(none) differs from one of v(all))."""
    return 1 + masked_obs[:, :3].max(axis=1, keepdims=True)


def brute_force_shapley(value, d: int) -> np.ndarray:
    """φ_i = Σ_S |S|! (d − |S| − 1)! / d! (v(S ∪ {i}) − v(S)) over visible sets S, term by term."""
    phi = np.zeros(d)
    for i in range(d):
        others = [j for j in range(d) if j != i]
        for size in range(d):
            for visible in itertools.combinations(others, size):
                weight = math.factorial(size) * math.factorial(d - size - 1) / math.factorial(d)
                phi[i] += weight * (value(set(visible) | {i}) - value(set(visible)))
    return phi


def test_shapley_attribution_by_hand_and_over_every_order():
    """The max game v(S) = 5 · max of the values seen (1, 2, 3): φ by hand (the airport game's
    dual: 5 · (1/3, 1/3 + 1/2, 1/3 + 1/2 + 1)); the permutation estimate over all d! orders is
    the exact value; a sampled estimate is efficient order by order and covers the truth."""
    plan = plan_shapley(3, 4)  # 2^3 = 8 coalitions <= the 4 · 2 + 2 that 4 orders would value: exact
    assert plan.method == "exact" and len(plan.hidden_rows) == 8
    game = np.array([1.0, 2.0, 3.0])
    values = 5 * ((1 - plan.hidden_rows) * game).max(axis=1)  # (8,) one start state; (8, 2) two alike
    exact = shapley_attribution(plan, plan.hidden_rows, np.stack([values, values], axis=1))
    np.testing.assert_allclose(exact.values, [5 / 3, 25 / 6, 55 / 6])
    assert exact.leave_one_out == [0.0, 0.0, 5.0] and (exact.full, exact.blind) == (15.0, 0.0)
    assert exact.ci95_starts == [0.0, 0.0, 0.0] and exact.orders == 0
    assert len(exact.coalition_values) == 8 and [[2], 10.0] in exact.coalition_values  # 3 hidden: 5 · max(1, 2)

    # A random game of 5 features with 4 start states: every order, each beside its reverse.
    d, rng = 5, np.random.default_rng(3)
    every_row = plan_shapley(d, 64).hidden_rows  # exact: all 32
    returns = rng.normal(size=(32, 4))
    row_of = {tuple(row.astype(int)): index for index, row in enumerate(every_row)}
    by_hand = brute_force_shapley(lambda visible: returns[row_of[tuple(int(j not in visible) for j in range(d))]].mean(), d)
    np.testing.assert_allclose(shapley_attribution(plan_shapley(d, 64), every_row, returns).values, by_hand)
    firsts = [order for order in itertools.permutations(range(d)) if order < order[::-1]]
    orders = np.array([row for order in firsts for row in (order, order[::-1])])
    every_order = shapley_attribution(ShapleyPlan(d, every_row, orders), every_row, returns)
    np.testing.assert_allclose(every_order.values, by_hand)

    sampled_plan = plan_shapley(d, 6, seed=1)  # 6 · 4 + 2 = 26 < 32 coalitions: sampled
    assert sampled_plan.method == "permutation" and sampled_plan.orders.shape == (6, d)
    np.testing.assert_array_equal(sampled_plan.orders[1], sampled_plan.orders[0][::-1])
    sampled = shapley_attribution(sampled_plan, every_row, returns)
    assert sum(sampled.values) == pytest.approx(sampled.full - sampled.blind)  # every order sums to v(F) − v(∅)
    assert np.all(np.abs(np.asarray(sampled.values) - by_hand) <= sampled.ci95) and min(sampled.ci95_orders) > 0
    with pytest.raises(ValueError, match="no value for 1 of the plan's hidden sets"):
        shapley_attribution(plan, plan.hidden_rows[1:], np.ones((7, 2)))
    with pytest.raises(ValueError, match="needs exact or at least 4 feature orders"):
        plan_shapley(3, 3)
    with pytest.raises(ValueError, match="exact Shapley values of d = 21 features value 2"):
        plan_shapley(21, "exact")


def test_gaps_to_the_worst_paired_and_by_welch(tmp_path):
    """Each set's gap above the worst: paired where the sets share start states (scipy's
    ttest_rel interval), Welch's otherwise (ttest_ind's); the sets not told apart, and the
    episodes that would tell the runner-up apart: the least n with n ≥ ((t_0.975 + t_0.8) · s / gap)²; an
    experiment's comparison of pairs audited with different N."""
    from scipy import stats

    from admissable_jax.audit import AuditResult, SetScore, compare_modes, write_audit

    returns = {(0,): [10.0, 12.0, 14.0, 16.0], (1,): [11.0, 13.0, 14.5, 17.5], (2,): [20.0, 24.0, 18.0, 26.0]}
    sets = [SetScore(hidden, (f"f{hidden[0]}",), float(np.mean(values)), 0.0, 0.0, values)
            for hidden, values in returns.items()]
    for paired, test in ((True, stats.ttest_rel), (False, lambda a, b: stats.ttest_ind(a, b, equal_var=False))):
        result = AuditResult("toy", "rollout", 4, 30.0, 0.0, [30.0] * 4, {1: sets}, ["f0", "f1", "f2"], {},
                             same_starts=paired)
        gaps = result.gaps_to_worst(1)
        assert [gap.entry.hidden for gap in gaps] == [(0,), (1,), (2,)] and (gaps[0].gap, gaps[0].ci95) == (0.0, 0.0)
        for gap in gaps[1:]:
            low, high = test(gap.entry.returns, returns[(0,)]).confidence_interval()
            assert (gap.gap, gap.ci95) == pytest.approx(((low + high) / 2, (high - low) / 2))
        assert [gap.tied for gap in gaps[1:]] == ([False, False] if paired else [True, False])
        # The gap 14.0 − 13.0 = 1. Paired: the differences 1, 1, 0.5, 1.5 have s² = 1/6; n = 3 gives
        # (t_0.975 + t_0.8 at 2 df)² s² = (4.303 + 1.061)² / 6 = 4.8 > 3, n = 4 gives (3.182 +
        # 0.978)² / 6 = 2.9 <= 4 (the normal approximation said 2). Welch: s² = 6.667 + 7.5 =
        # 14.17; n = 112 gives (1.9707 + 0.8434)² · 14.17 = 112.2 (at about 221 df), n = 113 about the same, <= 113.
        assert result.episodes_to_separate(1) == (4 if paired else 113)
        write_audit(result, str(tmp_path / str(paired)))
        report = (tmp_path / str(paired) / "report.md").read_text()
        assert f"| 2 | f1 | 1 | 14.0 ± 0.0 | 0.0% | +{gaps[1].gap:.1f} ± {gaps[1].ci95:.1f} |" in report
        if paired:
            assert ("The worst is told apart from every other set: the runner-up, f1, lies 1.0 ± 0.6 above it (the "
                    "gap's 95% interval, paired episode by episode, as every set's episode i starts from one state).") in report
        else:
            assert ("Not told apart from the worst (the gap's 95% interval holds 0; Welch's t, as the sets' episodes "
                    f"start from different states; each set compared alone): 1 of the other 2 sets ({{f1}}). About "
                    f"{result.episodes_to_separate(1)} episodes per set would tell the worst from the runner-up") in report

    # An experiment's pairs audited with tell_apart chose their own N: comparison.md gives the range.
    pairs = [dataclasses.replace(result, n_episodes=n, source={"mode": mode, "seed": 0, "checkpoint (env step)": 0})
             for n, mode in ((4, "adversarial"), (6, "uniform"))]
    assert "(N = 4–6 episodes per set, each audit's chosen by its pilot (`tell_apart`), `rollout`)" in compare_modes(pairs)
    # With mode worst audited too, adversarial − worst follows adversarial − uniform, under a line of its own.
    # (The worst pair's sets score 5 below the others': adversarial − worst is +5, − uniform 0.)
    lower = {1: [dataclasses.replace(entry, score=entry.score - 5) for entry in pairs[1].sets[1]]}
    worst_pair = dataclasses.replace(pairs[1], sets=lower, source={**pairs[1].source, "mode": "worst"})
    against_uniform, _, against_worst = compare_modes([*pairs, worst_pair]).partition(
        "Adversarial − worst (the paper's stochastic adversary against the deterministic one")
    assert "| k | measure | adversarial − uniform |" in against_uniform
    assert "adversarial − worst" not in against_uniform
    assert "| 1 | worst a_u | +0.0 |" in against_uniform and "| 1 | mean a_u | +0.0 |" in against_uniform
    assert "| k | measure | adversarial − worst |" in against_worst
    assert "| 1 | worst a_u | +5.0 |" in against_worst and "| 1 | mean a_u | +5.0 |" in against_worst
    # Pairs trained with sensors failing mid-episode, and scored so in training: both comparisons say so.
    from admissable_jax.audit.report import compare_modes_by_failure_time, training_failure_source

    trained = TrainConfig(env="point_mass", fail_at="20,0", score_fail_at="20").resolved()
    pairs = [dataclasses.replace(pair, source={**pair.source, **training_failure_source(vars(trained))}) for pair in pairs]
    said = ("The pairs were trained with sensors failing at env step 0,20 (`fail_at`) and scored in training with "
            "sensors failing at env step 20 (`score_fail_at`).")
    assert said in compare_modes(pairs) and said in compare_modes_by_failure_time({0: pairs, 20: pairs})
    assert training_failure_source(vars(TrainConfig(env="point_mass").resolved())) == {}

    # A set whose returns equal the worst's episode by episode (two hidden features the policy
    # ignores): a gap of 0 ± 0 tells nothing apart, and no N would.
    twin = SetScore((3,), ("f3",), sets[0].score, 0.0, 0.0, list(returns[(0,)]))
    result = AuditResult("toy", "rollout", 4, 30.0, 0.0, [30.0] * 4, {1: [*sets, twin]}, ["f0", "f1", "f2", "f3"], {})
    gaps = result.gaps_to_worst(1)
    assert (gaps[1].entry.hidden, gaps[1].gap, gaps[1].ci95, gaps[1].tied) == ((3,), 0.0, 0.0, True)
    assert result.episodes_to_separate(1) is None
    write_audit(result, str(tmp_path / "twin"))
    assert ("each set compared alone): 1 of the other 3 sets ({f3}). The runner-up's returns equal the worst's "
            "episode by episode.") in (tmp_path / "twin" / "report.md").read_text()


def test_the_drop_below_clean_reads_alike_whatever_the_returns_sign():
    """A set's drop: how far its a_u lies below the clean return, in percent of the clean
    return's size, so that an env whose returns are negative (HalfCheetah's early on, an env
    of one's own) reads as any other: a_u below the clean return by half its size is +50%
    either way."""
    from admissable_jax.audit.sets import drop_below_clean

    assert drop_below_clean(200.0, 100.0) == pytest.approx(50.0)
    assert drop_below_clean(-100.0, -150.0) == pytest.approx(50.0)
    assert drop_below_clean(-100.0, -50.0) == pytest.approx(-50.0)  # above the clean return: a negative drop
    assert math.isnan(drop_below_clean(0.0, -1.0))


def test_audit_steps_as_many_envs_at_once_as_training_scores():
    """slots=0: 32 on this CPU (a batched MJX step costs its batch size there), fewer where the
    audit has fewer episodes; slots=N: N. Without k=, the audit's sets are those the run
    trained against."""
    from types import SimpleNamespace

    from admissable_jax.audit.command import AuditConfig, _slots
    from admissable_jax.audit.sets import check_audit_size

    point_mass = SimpleNamespace(observation_size=4, config=TrainConfig(env="point_mass"))
    assert jax.default_backend() == "cpu"
    assert _slots(AuditConfig(run_dir="run", k="1,2", episodes=50), point_mass) == 32  # (4 + 6 + 1) × 50 episodes
    assert _slots(AuditConfig(run_dir="run", k="1", episodes=4), point_mass) == 20
    assert _slots(AuditConfig(run_dir="run", k="1", episodes=50, shapley="exact", slots=100), point_mass) == 100
    for trained, sets in (({}, 4), ({"k": 2}, 6), ({"k": 2, "up_to_k": True}, 4 + 6)):
        run = SimpleNamespace(observation_size=4, config=TrainConfig(env="point_mass", **trained))
        assert _slots(AuditConfig(run_dir="run", episodes=2), run) == (sets + 1) * 2
    # search=beam never lists U: Ant at k = 3 has 187,460 sets, more than can be listed, and a
    # beam of 4 ranks 4 · 105 of them a level; searched exhaustively it is refused by its count.
    ant = SimpleNamespace(observation_size=105, config=TrainConfig(env="ant"))
    assert _slots(AuditConfig(run_dir="run", k="3", episodes=2, search="beam", slots=10_000), ant) == (4 * 105 + 1) * 2
    with pytest.raises(ValueError, match="auditing k=3 on ant is 187,460 sets x 2 episodes in one rollout, over "
                                         "200,000: lower episodes=, drop the largest k or use search=beam"):
        check_audit_size("ant", 105, (3,), 2)


@pytest.mark.parametrize("ctrl_cs", [1, 2])
def test_a_ctrl_c_stops_the_audits_rollout_at_its_next_report(ctrl_cs, monkeypatch, caplog):
    """The audit's rollout is compiled programs that the host calls in turn, reporting between
    them; the audit compiles them and calls them on workers (audit.watch), so a Ctrl-C is
    heard at once, however long a call runs, and the rollout's next report ends it. A second
    Ctrl-C while the rollout is still on its way to that report ends the wait at once and
    ends the bar's line first (the command then exits at once), so that the command's last
    line stands on a line of its own."""
    import signal
    import threading
    import time

    from admissable_jax.audit import watch
    from admissable_jax.cli import compiled_in_background

    reports, closed_in_main_thread = [], []
    report, close = watch._Watch.report, watch._Watch.close

    def slow_to_stop(self, finished):
        reports.append(finished)
        if self.stop.is_set() and ctrl_cs == 2:
            time.sleep(1.0)  # a long step before the report that stops it
        report(self, finished)

    monkeypatch.setattr(watch._Watch, "report", slow_to_stop)
    monkeypatch.setattr(watch._Watch, "close", lambda self: closed_in_main_thread.append(
        threading.current_thread() is threading.main_thread()) or close(self))
    steps = 200_000

    segment = compiled_in_background(jax.jit(jnp.sin).lower(jnp.ones(4)))
    stopped = threading.Event()

    def rollout(report):
        x = jnp.ones(4)
        try:
            for i in range(steps):
                x = jax.block_until_ready(segment(x))
                report(i)
            return x
        finally:
            stopped.set()

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    ctrl_c = [threading.Timer(0.5 + 0.2 * n, lambda: signal.pthread_kill(threading.main_thread().ident, signal.SIGINT))
              for n in range(ctrl_cs)]
    try:
        for timer in ctrl_c:
            timer.start()
        with caplog.at_level("ERROR"):
            with pytest.raises(KeyboardInterrupt):
                watch.watched_rollout(rollout, steps, draw=True)
            # One Ctrl-C waits for the worker, which closes the bar; after a second the worker is
            # still on its way to stop, and the main thread has closed it.
            assert closed_in_main_thread == [ctrl_cs == 2]
            assert stopped.wait(5)  # the worker stops by itself
    finally:
        for timer in ctrl_c:
            timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert 0 < len(reports) < steps
    assert closed_in_main_thread == [True] * (ctrl_cs - 1) + [False]
    assert not [record for record in caplog.records if record.name.startswith("jax")]
    # The bar's time left is at the audit's average rate: slots end episodes in bursts, and
    # tqdm's default smoothing swung a Hopper audit's from 5 to 26 minutes and back.
    bursty = watch._Watch(100, draw=True)
    bursty.report(10)
    assert bursty.bar.smoothing == 0
    bursty.close()


def test_audit_of_any_gymnasium_policy(tmp_path, capfd, monkeypatch):
    """audit_gymnasium on tests/test_wrappers.py's ConstantFeatures env (observes 1, 2, 3;
    earns 5 · the sum it sees): hand-computed a_u for every set of 1 and 2 features, the worst,
    the mean over the sets, and the same report as a run's audit."""
    monkeypatch.chdir(tmp_path)  # where MuJoCo would write MUJOCO_LOG.TXT
    from test_wrappers import sum_of_visible  # registers ConstantFeatures-v0

    from admissable_jax.audit import audit_gymnasium, write_audit
    from admissable_jax.audit.sets import audit_sizes

    result = audit_gymnasium("ConstantFeatures-v0", sum_of_visible, ks=(1, 2), n_episodes=2, num_envs=3)
    assert result.clean_score == 30.0 and result.n_episodes == 2 and result.feature_names == ["feature 0", "feature 1", "feature 2"]
    assert [(entry.hidden, entry.score) for entry in result.sets[1]] == [((0,), 25.0), ((1,), 20.0), ((2,), 15.0)]
    assert [(entry.hidden, entry.score) for entry in result.sets[2]] == [((0, 1), 15.0), ((0, 2), 10.0), ((1, 2), 5.0)]
    assert result.worst(2, 1)[0].drop_percent == pytest.approx(100 * 25 / 30)
    assert (result.mean(1), result.mean(2)) == (20.0, 10.0)
    assert repr(result) == (  # shown in a notebook: what was found, not every episode's return
        "<AuditResult of ConstantFeatures-v0, 2 episodes per set: clean 30.0 ± 0.0\n"
        "  k=1: worst feature 2 ([2]): a_u 15.0 ± 0.0, 50.0% below clean 30.0; mean over the 3 sets 20.0; told apart "
        "from every other set\n"
        "  k=2: worst feature 1, feature 2 ([1, 2]): a_u 5.0 ± 0.0, 83.3% below clean 30.0; mean over the 3 sets 10.0; "
        "told apart from every other set>")
    written = write_audit(result, str(tmp_path / "audit"))
    assert sorted(os.path.basename(path) for path in written) == ["audit.json", "pairs_k2.png", "report.md", "scores_k1.png",
                                                                   "worst_by_k.png"]
    report = (tmp_path / "audit" / "report.md").read_text()
    assert "Gymnasium env ConstantFeatures-v0, policy sum_of_visible" in report
    assert "| 1 | feature 1, feature 2 | 1, 2 | 5.0 ± 0.0 | 83.3% |" in report  # an env that names no feature
    assert "N = 2 episodes of the policy as given, each set's from the vector env's own resets" in report
    assert ("Mean over all 3 sets (the average case, u drawn uniformly): 10.0, 66.7% below clean; the worst: 5.0."
            in report)  # k = 2: the mean's own drop, (30 − 10) / 30
    with pytest.raises(ValueError, match="^k must be set sizes 1 <= k < d = 3, got 3$"):
        audit_gymnasium("ConstantFeatures-v0", sum_of_visible, ks=(3,))
    with pytest.raises(TypeError, match=r"^ks must be set sizes \(ints\), got \('1',\)$"):
        audit_gymnasium("ConstantFeatures-v0", sum_of_visible, ks=("1",))
    # One int is one size, and a size given twice is scored once (as audit k=1,1 reads them).
    assert audit_sizes(2, 3) == audit_sizes((2, 2), 3) == (2,) and audit_sizes((2, 1), 3) == (1, 2)

    # What each feature is worth to a policy that acts on the largest value it sees: the max
    # game's Shapley values (a blind 1 added to every action moves none), beside the loss of
    # hiding each alone (0, 0, 5: only 3 is missed).
    worth = audit_gymnasium("ConstantFeatures-v0", max_of_visible, ks=(1,), n_episodes=2, num_envs=3, shapley="exact")
    np.testing.assert_allclose(worth.shapley.values, [5 / 3, 25 / 6, 55 / 6])
    assert worth.shapley.leave_one_out == [0.0, 0.0, 5.0] and [entry.score for entry in worth.sets[1]] == [20, 20, 15]
    written = write_audit(worth, str(tmp_path / "worth"))
    assert os.path.basename(written[-1]) == "shapley.png"
    report = (tmp_path / "worth" / "report.md").read_text()
    assert "v(all) = 20.0, v(none) = 5.0, and the φ_i sum to v(all) − v(none) = 15.0. Beside it" in report
    assert "| 2 | feature 1 | 1 | 4.2 ± 0.0 | 27.8% | 0.0 |" in report

    # From the command line: policy=MODULE:NAME on gym=ENV_ID, the same numbers.
    # slots=3: three Gymnasium envs stepped at once, so every batch the policy sees holds 3.
    assert audit_main(["policy=test_audit:counted_sum_of_visible", "gym=ConstantFeatures-v0", "k=1,2", "episodes=2",
                       "slots=3", f"out={tmp_path / 'cli'}"]) == 0
    assert set(BATCH_SIZES) == {3}
    record = json.loads((tmp_path / "cli" / "audit.json").read_text())
    assert [entry["score"] for entry in record["sets"]["2"]] == [15.0, 10.0, 5.0]
    assert record["source"]["policy"] == "test_audit:counted_sum_of_visible"  # (it said "call", its wrapper's name)
    assert ("k=2: worst feature 1, feature 2 ([1, 2]): a_u 5.0 ± 0.0, 83.3% below clean 30.0; mean over the 3 sets "
            "10.0; told apart from every other set") in capfd.readouterr().out
    # Random sensor failure on a Gymnasium env: each mask's return by hand, 5 · (6 − what it
    # hides), R(p) their mean; the sets' scores as without it.
    # The masks follow the law: each feature lost with probability p, independently of the others.
    law = plan_dropout(3, (0.2,), 20_000, seed=0).hidden_rows
    assert np.abs(law.mean(axis=0) - 0.2).max() < 4 * np.sqrt(0.2 * 0.8 / 20_000)
    assert abs((law[:, 0] * law[:, 2]).mean() - 0.04) < 4 * np.sqrt(0.04 * 0.96 / 20_000)  # both lost: p²
    plan = plan_dropout(3, (0.2, 0.6), 8, seed=1)
    failing = audit_gymnasium("ConstantFeatures-v0", sum_of_visible, ks=(1,), n_episodes=2, num_envs=3, dropout=plan)
    by_hand = (5 * (6 - plan.hidden_rows @ np.array([1.0, 2.0, 3.0]))).reshape(2, 8)
    assert [entry.score for entry in failing.dropout] == pytest.approx(by_hand.mean(axis=1))
    assert [entry.score for entry in failing.sets[1]] == [25.0, 20.0, 15.0]
    # Sensors that fail at env step 2 of each 5-step episode: 2 · 6 + 3 · (6 − the hidden value).
    late = audit_gymnasium("ConstantFeatures-v0", sum_of_visible, ks=(1,), n_episodes=2, num_envs=3, fail_at=2)
    assert [entry.score for entry in late.sets[1]] == [27.0, 24.0, 21.0] and late.clean_score == 30.0
    assert (late.fail_at, late.clean_lengths, late.ended_before_failing) == (2, [5, 5], 0)
    write_audit(late, str(tmp_path / "late"))
    report = (tmp_path / "late" / "report.md").read_text()
    assert ("was hidden (hidden features read 0, with the 0/1 indicator of the paper's masked observation) from env step 2 "
            "of each episode on, every feature seen before it (a sensor that fails mid-episode, `fail_at`;") in report
    assert "The sensors fail at env step 2, and every clean episode ran past it (the clean episodes last 5 env steps)." in report
    # ...and at step 5, after every episode's end: nothing fails, which the command says, into a folder named for it.
    assert audit_main(["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "episodes=2", "fail_at=5"]) == 0
    record = json.loads((tmp_path / "audit-ConstantFeatures-v0-sum_of_visible-fail5" / "audit.json").read_text())
    assert record["fail_at"] == 5 and [entry["score"] for entry in record["sets"]["1"]] == [30.0] * 3
    assert ("warning: every clean episode had ended by env step 5, where the sensors fail: the sets' returns are the "
            "clean one's; give a smaller fail_at") in capfd.readouterr().err
    # Several failure steps: each audited into its folder, then a row per step (and the clean
    # episodes ended by then) in failure_times.md, and its chart.
    assert audit_main(["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "episodes=2", "fail_at=5,0,2"]) == 0
    times = tmp_path / "audit-sum_of_visible-failure-times"
    assert sorted(os.listdir(times)) == ["fail0", "fail2", "fail5", "failure_times.md", "failure_times.png"]
    table = (times / "failure_times.md").read_text()
    assert table.startswith("# Robustness by when the sensors fail: ConstantFeatures-v0, Gymnasium env "
                            "ConstantFeatures-v0, policy test_wrappers:sum_of_visible\n")
    assert ("| 0 (0 of 2) | 30.0 ± 0.0 | 15.0 ± 0.0 (feature 2) | 20.0 |\n"
            "| 2 (0 of 2) | 30.0 ± 0.0 | 21.0 ± 0.0 (feature 2) | 24.0 |\n"
            "| 5 (2 of 2) | 30.0 ± 0.0 | 30.0 ± 0.0 (feature 0) | 30.0 |\n") in table
    printed = capfd.readouterr()
    assert "fail_at 2: k=1: worst feature 2 ([2]): a_u 21.0 ± 0.0" in printed.out and table in printed.out
    from PIL import Image  # the chart, and beside it each feature's a_u by step: two panels side by side

    assert Image.open(times / "failure_times.png").size[0] > 1.6 * Image.open(times / "fail0" / "scores_k1.png").size[0]
    assert "fail_at 5: warning: every clean episode had ended by env step 5" in printed.err
    # An exported policy (python -m admissable_jax.export), policy=FILE.npz: its run names the
    # Gymnasium env and the set sizes (k = 2 with up_to_k: 1 and 2) and its features' names,
    # the numbers are its masked batches' audited from Python, and the report says whence it came.
    exported = ExportedPolicy((np.array([[0.01]] * 3 + [[0.0]] * 3, np.float32), np.ones((1, 1), np.float32)),
                              (np.zeros(1, np.float32), np.zeros(1, np.float32)), np.array([-100.0], np.float32),
                              np.array([100.0], np.float32), ("one", "two", "three"),
                              {"run": "runs/x", "env": "constant", "gymnasium_id": "ConstantFeatures-v0",
                               "missingness": "uniform", "seed": 3, "k": 2, "up_to_k": True, "env_steps": 500,
                               "best_min_score": 4.25, "score_fail_at": "0,2"})
    # Its default folder lies beside the file, not here: export names every run's file alike.
    (tmp_path / "x" / "exported").mkdir(parents=True)
    exported.save(str(tmp_path / "x" / "exported" / "constant.npz"))
    assert audit_main([f"policy={tmp_path / 'x' / 'exported' / 'constant.npz'}", "episodes=2"]) == 0
    record = json.loads((tmp_path / "x" / "exported" / "audit-ConstantFeatures-v0-constant" / "audit.json").read_text())
    direct = audit_gymnasium("ConstantFeatures-v0", exported.masked, ks=(1, 2), n_episodes=2)
    assert sorted(record["sets"]) == ["1", "2"] and record["feature_names"] == ["one", "two", "three"]
    for k in (1, 2):
        assert [entry["score"] for entry in record["sets"][str(k)]] == [entry.score for entry in direct.sets[k]]
    # By hand: the action is 100 · tanh(0.01 · the sum it sees) (tanh squashes, then [-100, 100]), 5 steps an
    # episode; hiding feature 0, 1 or 2 (values 1, 2, 3) leaves sums of 5, 4 and 3.
    assert record["clean_score"] == pytest.approx(500 * np.tanh(0.06), rel=1e-5)
    assert [entry["score"] for entry in record["sets"]["1"]] == pytest.approx(500 * np.tanh(np.array([5, 4, 3]) / 100),
                                                                              rel=1e-5)
    assert record["source"] == {"Gymnasium env": "ConstantFeatures-v0", "policy": str(tmp_path / "x" / "exported" / "constant.npz"),
                                "exported from": "runs/x (uniform, seed 3) at env step 500, its best scoring "
                                                 "(training's min_u a_u 4.2)",
                                "scored in training with sensors failing at env step": "0,2"}
    # A folder holding another policy's audit is never written over: one line, exit 2, before
    # the rollout, the audit there left as it was; the same policy's is (an audit again).
    held = tmp_path / "audit-ConstantFeatures-v0-sum_of_visible-fail5"
    before = (held / "audit.json").read_text()
    capfd.readouterr()
    assert audit_main([f"policy={tmp_path / 'x' / 'exported' / 'constant.npz'}", "episodes=2", f"out={held}"]) == 2
    assert capfd.readouterr().err.strip() == (
        f"error: {held} holds the audit of another policy (ConstantFeatures-v0, test_wrappers:sum_of_visible): it is "
        "left as it is; give another out= (or remove it)")
    assert (held / "audit.json").read_text() == before
    assert audit_main(["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "episodes=3", "fail_at=5"]) == 0
    assert json.loads((held / "audit.json").read_text())["n_episodes"] == 3
    # An exported policy is the run's it came from, however its path is given (here relative).
    exported_audit = tmp_path / "x" / "exported" / "audit-ConstantFeatures-v0-constant"
    assert audit_main(["policy=x/exported/constant.npz", "episodes=3", f"out={exported_audit}"]) == 0
    assert json.loads((exported_audit / "audit.json").read_text())["n_episodes"] == 3
    # tell_apart: every return here is constant, so no gap needs more episodes than the pilot's 2.
    assert audit_main(["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "k=1,2", "episodes=2",
                       "tell_apart=true", f"out={tmp_path / 'told'}"]) == 0
    told = json.loads((tmp_path / "told" / "audit.json").read_text())
    assert told["pilot"] == {"episodes": 2, "seed": 0, "needed": {"1": None, "2": None}, "chosen": 2, "most": 1000}
    assert [entry["score"] for entry in told["sets"]["2"]] == [15.0, 10.0, 5.0] and not told["same_starts"]
    assert "N = 2 episodes per set, chosen by a pilot of 2" in capfd.readouterr().out
    # The report says whose start states each audit ran from: the pilot's seed, then the next.
    assert "a pilot audit of 2 episodes per set (the start states of seed 0; these are seed 1's)" in (
        tmp_path / "told" / "report.md").read_text()
    for args, message in [
        (["policy=test_wrappers:nothing", "gym=ConstantFeatures-v0"], "cannot load policy=test_wrappers:nothing: module"),
        (["policy=test_wrappers:sum_of_visible", "gym=NoSuchEnv-v0"], "cannot make the Gymnasium env 'NoSuchEnv-v0'"),
        (["policy=test_wrappers:sum_of_visible"], "a Python policy is audited with policy=MODULE:NAME and gym=ENV_ID"),
        (["policy=test_wrappers", "gym=ConstantFeatures-v0"], "policy must be MODULE:NAME"),
        (["policy=test_audit:N", "gym=ConstantFeatures-v0"],  # a name that is no function (a typo's neighbour)
         "policy=test_audit:N is not callable (its type: int): give a function masked_obs_batch -> actions"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "shapley=3"],
         "shapley must be 0 (none), exact, or at least 4 feature orders, got '3'"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "k=a"],
         "k must be a comma list of set sizes, e.g. 1,2; got 'a'"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "episodes=1"],
         "episodes must be at least 2 for a confidence interval"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "top=0"], "top must be at least 1, got 0"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "slots=-1"], "slots must be >= 0, got -1"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "seed=-1"],
         "seed must be >= 0 and step an env step or -1 (the latest), got seed=-1, step=-1"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "step=-2"], "seed must be >= 0 and step"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "score_estimator=critic"],
         "a Python policy is audited by rollouts of every set (it has no critic to estimate with)"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "score_horizon=0"],
         "score_estimator must be one of rollout, critic, horizon and score_horizon >= 1"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "dropout=0.1,1.5"],
         "dropout rates must lie in (0, 1], got '0.1,1.5'"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "dropout=often"],
         "dropout must be a comma list of failure rates in (0, 1], e.g. 0.05,0.1,0.2; got 'often'"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "dropout=0.1", "dropout_masks=1"],
         "dropout_masks must be at least 2 for an interval, got 1"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "fail_at=-1"],
         "fail_at must be an env step >= 0 (0: hidden from the start), got -1"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "fail_at=soon"],
         "fail_at must be an env step or a comma list of them, e.g. 0,50,100; got 'soon'"),
        (["some_run", "steps=all", "fail_at=0,50"], "a list of fail_at audits one checkpoint (of a run, of an experiment's "
                                                     "pairs, or policy=): give steps= one fail_at"),
        (["policy=test_wrappers:sum_of_visible", "gym=Hopper-v5", "fail_at=1000"],
         "fail_at=1000 is not below the episodes' 1000 steps: nothing would fail"),
        (["some_run", "search=beam", "ranker=critic", "fail_at=5"],
         "fail_at=5 needs rollouts: give ranker=rollout (the critic values a start with u hidden from it"),
        (["policy=test_wrappers:sum_of_visible", "gym=ConstantFeatures-v0", "dropout=0.5", "dropout_masks=100000",
          "episodes=2"], "auditing k=1 on ConstantFeatures-v0 is 100,003 sets x 2 episodes in one rollout, over 200,000: "
                         "lower episodes=, drop the largest k or give dropout= fewer rates or dropout_masks= fewer masks"),
        ([], "give the run directory: python -m admissable_jax.audit RUN_DIR [k=1,2] [episodes=50]"),
        (["some_run", "search=guess"], "search must be one of exact, beam, got 'guess'"),
        (["some_run", "search=beam", "beam_width=0"], "beam_width must be >= 1, got 0"),
        # checked on the env itself before anything is written (HalfCheetah's settotalmass
        # deprecation, Gymnasium's file, kept out of the output and the working directory)
        (["policy=test_wrappers:sum_of_visible", "gym=HalfCheetah-v5", "k=17"], "k must be set sizes 1 <= k < d = 17, got 17"),
        # our env names as env= takes them name the Gymnasium env (it said "Environment `halfcheetah` doesn't exist")
        (["policy=test_wrappers:sum_of_visible", "gym=halfcheetah", "k=17"], "k must be set sizes 1 <= k < d = 17, got 17"),
    ]:
        try:
            status = audit_main([*args, f"out={tmp_path / 'never'}"])
        except SystemExit as exit_info:  # refused by the parser's validation
            status = exit_info.code
        error = capfd.readouterr().err.strip().splitlines()
        assert status == 2 and len(error) == 1 and error[0].startswith(f"error: {message}"), error
    assert not (tmp_path / "never").exists() and not (tmp_path / "MUJOCO_LOG.TXT").exists()
    # A bug in one's own policy: its exception named with it in the last line, exit 2, not a
    # traceback through the rollout; the folder made for the report is gone again.
    assert audit_main(["policy=test_audit:failing_policy", "gym=ConstantFeatures-v0", "episodes=2",
                       f"out={tmp_path / 'failed'}"]) == 2
    assert capfd.readouterr().err.strip().splitlines()[-1] == (
        "error: policy=test_audit:failing_policy raised ZeroDivisionError: integer division or modulo by zero")
    assert not (tmp_path / "failed").exists()
    # Ctrl-C while the policy runs: one line that says what was written, exit 130.
    assert audit_main(["policy=test_audit:interrupted_policy", "gym=ConstantFeatures-v0", "episodes=2",
                       f"out={tmp_path / 'stopped'}"]) == 130
    assert capfd.readouterr().err.strip().splitlines()[-1] == ("interrupted: the audit in progress wrote nothing; audit "
                                                              "folders finished before it are kept")
    assert not (tmp_path / "stopped").exists()  # made before the rollout, and gone with it


BATCH_SIZES: list[int] = []  # the batches counted_sum_of_visible was called with


def counted_sum_of_visible(obs):
    """test_wrappers' sum_of_visible, recording each batch's size (the envs stepped at once)."""
    from test_wrappers import sum_of_visible

    BATCH_SIZES.append(len(obs))
    return sum_of_visible(obs)


def failing_policy(obs):
    return 1 // 0  # a bug in one's own policy


def interrupted_policy(obs):
    raise KeyboardInterrupt  # as a Ctrl-C does when it lands while the policy runs


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """A short adversarial run whose scorings are 3-step horizon estimates (its scoring pool
    of 16 slots more than the 10 episodes: those beyond never run), trained with its sensors
    failing at env step 0 or 5 of each episode (which its audit's report names)."""
    return train_fn(dataclasses.replace(SHORT_RUN, out=str(tmp_path_factory.mktemp("audit") / "pm")))


SHORT_RUN = TrainConfig(env="point_mass", total_steps=600, score_every=200, num_envs=4, learning_starts=200,
                        episode_length=12, score_episodes=2, score_envs=16, batch_size=32, buffer_size=1000, hidden_size=16,
                        score_estimator="horizon", score_horizon=3, checkpoint_every=1, keep_checkpoints=3,
                        progress=False, fail_at="5,0")


def test_several_runs_audited_each_and_compared_by_curve(short_run, tmp_path, capsys):
    """``audit RUN RUN ...``: each run audited as it would be alone (into its own folder), then
    comparison.md sets their curves side by side, as plot names them: the mode and the settings
    the runs differ in (here fail_at, and l, which uniform runs do not read), each curve's runs
    its seeds, and each adversarial curve against the uniform curve of its other settings, where
    there is one; with a list of
    fail_at, the curves' worst a_u by failure step. Runs of two envs are refused in one line."""
    uniform = dataclasses.replace(SHORT_RUN, missingness="uniform")
    runs = [shutil.copytree(short_run.run_dir, tmp_path / "failing-s0"),
            train_fn(dataclasses.replace(SHORT_RUN, seed=1, out=str(tmp_path / "failing-s1"))).run_dir,
            train_fn(dataclasses.replace(SHORT_RUN, fail_at="0", lower_bound=1.0, out=str(tmp_path / "from-start"))).run_dir,
            *[train_fn(dataclasses.replace(uniform, seed=seed, out=str(tmp_path / f"uniform-s{seed}"))).run_dir
              for seed in (0, 1)]]
    assert audit_main([*map(str, runs), "k=1", "episodes=2", f"out={tmp_path / 'compared'}"]) == 0
    printed = capsys.readouterr().out
    worst = {}
    for run in runs:
        record = json.loads((pathlib.Path(run) / "audit-step600" / "audit.json").read_text())
        worst[os.path.basename(run)] = min(entry["score"] for entry in record["sets"]["1"])
    comparison = (tmp_path / "compared" / "comparison.md").read_text()
    assert comparison.startswith("# Robustness audit of 5 runs: point_mass, checkpoint 600\n")
    failing = np.array([worst["failing-s0"], worst["failing-s1"]])
    baseline = np.array([worst["uniform-s0"], worst["uniform-s1"]])
    assert f"| 1 | adversarial, fail_at=0,5, lower_bound=0 | 2 | {estimate(failing)} |" in comparison
    assert f"| 1 | adversarial, fail_at=0, lower_bound=1 | 1 | {estimate(np.array([worst['from-start']]))} |" in comparison
    assert f"| 1 | uniform, fail_at=0,5 | 2 | {estimate(baseline)} |" in comparison
    differences = comparison.split("adversarial − uniform")[-1]  # (fail_at=0 has no uniform curve: no row)
    assert (f"| 1 | worst a_u (adversarial, fail_at=0,5, lower_bound=0) | {failing.mean() - baseline.mean():+.1f} | ["
            in differences)
    assert "(adversarial, fail_at=0, lower_bound=1)" not in differences
    assert "The pairs were" not in comparison  # (they differ in it: the curves say how)
    assert curve_mode("adversarial, fail_at=0,5, lower_bound=0") == "adversarial"  # (its colours: the mode's shades)
    assert "adversarial, fail_at=0,5, lower_bound=0 seed 1: k=1: worst" in printed and comparison in printed
    # At two failure steps: every run at each, then the curves by failure step.
    assert audit_main([*map(str, runs), "k=1", "episodes=2", "fail_at=3,0", f"out={tmp_path / 'times'}"]) == 0
    table = (tmp_path / "times" / "failure_times.md").read_text()
    for step in (0, 3):
        late = [min(entry["score"] for entry in json.loads(
            (pathlib.Path(run) / f"audit-step600{'-fail3' * bool(step)}" / "audit.json").read_text())["sets"]["1"])
            for run in runs]
        assert (f"| 1 | {step} | {estimate(np.array(late[2:3]))} | {estimate(np.array(late[:2]))} | "
                f"{estimate(np.array(late[3:]))} |") in table
        assert (f"| 1 | {step} | adversarial, fail_at=0,5, lower_bound=0 | {np.mean(late[:2]) - np.mean(late[3:]):+.1f} | ["
                in table)
    # The same run elsewhere is the same policy: moved with its audits in it, reached by a link, or
    # copied, its audit there is written over (an audit again); another run of the same settings's
    # audit is not, nor a moved run's audit outside its folder (either run's, for all it knows).
    moved, link = tmp_path / "moved-s1", tmp_path / "link-s0"
    os.rename(runs[1], moved)
    link.symlink_to(runs[0])
    copied = shutil.copytree(runs[3], tmp_path / "copied-u0")
    assert audit_main([str(moved), str(link), str(copied), "k=1", "episodes=3", f"out={tmp_path / 'again'}"]) == 0
    for run in (moved, link, copied):
        record = json.loads((run / "audit-step600" / "audit.json").read_text())
        assert (record["n_episodes"], record["source"]["run"]) == (3, str(run))
    rerun = shutil.copytree(moved, tmp_path / "rerun-s1", ignore=shutil.ignore_patterns("audit-*"))
    first, *later = (rerun / "invocations.jsonl").read_text().splitlines(keepends=True)
    (rerun / "invocations.jsonl").write_text("".join([first.replace('"started": "', '"started": "1'), *later]))
    outside = shutil.copytree(pathlib.Path(runs[4]) / "audit-step600", tmp_path / "outside")
    os.rename(runs[4], tmp_path / "moved-u1")
    capsys.readouterr()
    for run, out, earlier in [(rerun, moved / "audit-step600", moved), (tmp_path / "moved-u1", outside, runs[4])]:
        before = (out / "audit.json").read_text()
        assert audit_main([str(run), "k=1", "episodes=2", f"out={out}"]) == 2
        assert capsys.readouterr().err.strip().splitlines()[-1] == (
            f"error: {out} holds the audit of another policy ({earlier}, 600): it is left as it is; give another out= "
            "(or remove it)")
        assert (out / "audit.json").read_text() == before
    other_env = shutil.copytree(short_run.run_dir, tmp_path / "hopper")  # (refused before its policy is read)
    config_path = other_env / "config.yaml"
    config_path.write_text(config_path.read_text().replace("env: point_mass", "env: Hopper-v5"))
    assert audit_main([str(runs[0]), str(other_env), "k=1", "episodes=2"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == ("error: the runs compared must share one env, got "
                                                                "Hopper-v5, point_mass: audit each env's apart")


def test_training_scores_with_the_chosen_estimator(short_run):
    """score_estimator=horizon in training: each row says so, every estimate ran at most H = 3
    steps, and the adversary's p_miss is the inverse-score distribution of the estimates."""
    for row in short_run.scores:
        assert row["score_estimator"] == "horizon"
        assert 0 < row["mean_episode_length"] <= 3
        inverse = 1 / (np.maximum(np.asarray(row["scores"]), 0.0) + 1e-8)
        np.testing.assert_allclose(row["p_miss"], inverse / inverse.sum(), rtol=1e-4)
    assert short_run.scores[-1]["scores"] != short_run.scores[0]["scores"]


def test_score_estimators_benchmark_compares_each_estimator_with_the_rollout(short_run, tmp_path, monkeypatch):
    """benchmarks/score_estimators.py on a run whose scoring pool (score_envs = 16) is larger
    than the (|U| + 1) · N = 10 episodes scored: one record per estimator, each against the
    rollout's scores from the same start states, which are score_missingness's."""
    import common  # benchmarks/ is on the tests' path (conftest.py)
    import score_estimators
    from scipy import stats

    from admissable_jax.method import inverse_score_p_miss

    monkeypatch.setattr(common, "RESULTS_DIR", str(tmp_path))
    score_estimators.main([f"runs={short_run.run_dir}", "horizons=0,3", "n_episodes=2", "seed=5"])
    with open(tmp_path / "score_estimators.jsonl") as file:
        records = [json.loads(line) for line in file]
    policy = load_policy(short_run.run_dir)
    sets = jnp.asarray(candidate_sets(4, 1))
    rollout = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(5), sets, 2)
    estimates = [estimate_scores(ENV, policy.trainer.policy, policy.actor_params, policy.trainer.critic_values,
                                 policy.critic_params, jax.random.key(5), sets, 2, horizon, short_run.config.gamma)
                 for horizon in (0, 3)]
    assert [(record["estimator"], record["horizon"], record["physics_steps"]) for record in records] == [
        ("critic", 0, 0), ("horizon", 3, 3)]
    for record, estimated in zip(records, estimates):
        assert record["checkpoint"] == policy.step and record["sets"] == 4 and record["n_episodes"] == 2
        np.testing.assert_allclose(record["rollout_scores"], rollout.scores, rtol=1e-5)
        np.testing.assert_allclose(record["scores"], estimated.scores, rtol=1e-5)
        assert record["rollout_physics_steps"] == int(rollout.loop_steps)
        assert record["spearman"] == pytest.approx(stats.spearmanr(record["scores"], record["rollout_scores"]).statistic)
        assert record["argmin_agrees"] == (np.argmin(record["scores"]) == np.argmin(record["rollout_scores"]))
        ours, theirs = (inverse_score_p_miss(np.asarray(scores), 0.0, 1e-8)
                        for scores in (record["scores"], record["rollout_scores"]))
        assert record["p_miss_tv"] == pytest.approx(0.5 * np.abs(ours - theirs).sum())


def test_audit_report_equals_its_json_and_score_missingness(short_run, tmp_path, capsys):
    out = str(tmp_path / "audit")
    assert audit_main([short_run.run_dir, "k=1,2", "episodes=6", f"out={out}", "seed=4", "shapley=6",
                       "dropout=0.5,0.25", "dropout_masks=4"]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    # The long part (compile and rollouts) is announced, then timed, as training's compile is;
    # between the two, the progress over the rollout's episodes: (4 + 6 sets, the 5 more of the
    # 16 coalitions, clean) × 6, here (stderr no terminal, as a job's log) a line at its end.
    assert re.fullmatch(r"(auditing checkpoint \d+ of point_mass for k=1,2 \(exact search, 6 episodes per set, jax "
                        r"physics on cpu; compiling included\))\.\.\.\n96 of 96 episodes \(100%\), 00:\d\d elapsed, "
                        r"about 00:00 left at [\d.]+episode/s\n\1: done in \d+\.\d s\n", captured.err), captured.err
    assert sorted(os.listdir(out)) == ["audit.json", "pairs_k2.png", "report.md", "scores_k1.png", "shapley.png",
                                       "worst_by_k.png"]
    with open(os.path.join(out, "audit.json")) as file:
        record = json.load(file)
    assert [len(record["sets"][k]) for k in ("1", "2")] == [4, 6]
    assert record["source"]["trained with sensors failing at env step"] == "0,5"  # its config's sorted list

    # Every a_u is score_missingness's for the same policy, seed and N (k = 1 and k = 2).
    policy = load_policy(short_run.run_dir)
    for k in (1, 2):
        finished = []  # what the rollout tells a bar after each segment: every episode runs at once here
        direct = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(4),
                                   jnp.asarray(candidate_sets(4, k)), 6, progress=finished.append)
        ends = [*range(SEGMENT_LOOP_STEPS, int(direct.loop_steps), SEGMENT_LOOP_STEPS), int(direct.loop_steps)]
        assert finished == [int((direct.lengths <= step).sum()) for step in ends]
        np.testing.assert_allclose([entry["score"] for entry in record["sets"][str(k)]], direct.scores, rtol=1e-5)
        np.testing.assert_allclose(record["clean_score"], direct.clean_score, rtol=1e-5)
    # Shapley values (d = 4: all 16 coalitions, in the same rollout): term by term from
    # score_missingness's values of every hidden set, and leave-one-out from the k = 1 rows.
    every_set = jnp.asarray([[float(j in hidden) for j in range(4)] for size in range(1, 5)
                             for hidden in itertools.combinations(range(4), size)])
    direct = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(4), every_set, 6)
    value_of = {frozenset(np.flatnonzero(1 - np.asarray(row)).tolist()): score for row, score in zip(every_set, direct.scores)}
    value_of[frozenset(range(4))] = direct.clean_score
    worth = record["shapley"]
    assert worth["method"] == "exact" and worth["coalitions"] == 16
    np.testing.assert_allclose(worth["values"], brute_force_shapley(lambda visible: value_of[frozenset(visible)], 4),
                               rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(worth["leave_one_out"], [record["clean_score"] - entry["score"] for entry in record["sets"]["1"]])
    # Random sensor failure (dropout=0.25,0.5, 4 masks each, from seed 4's draws; here among the
    # coalitions, so the rollout stays as it was): each mask is valued as its set is, the clean
    # return where it hides nothing; R(p) is their mean.
    masks = plan_dropout(4, (0.25, 0.5), 4, seed=4).hidden_rows
    by_hand = np.reshape([value_of[frozenset(np.flatnonzero(1 - row).tolist())] for row in masks], (2, 4))
    assert [entry["rate"] for entry in record["dropout"]] == [0.25, 0.5]
    np.testing.assert_allclose([entry["score"] for entry in record["dropout"]], by_hand.mean(axis=1), rtol=1e-4)
    np.testing.assert_allclose([entry["ci95"] for entry in record["dropout"]],
                               3.1824 * by_hand.std(axis=1, ddof=1) / 2, rtol=1e-4)  # Student's t, 3 degrees of freedom
    assert [entry["mean_hidden"] for entry in record["dropout"]] == masks.reshape(2, 4, 4).sum(axis=2).mean(axis=1).tolist()
    assert re.search(r"^random failure: p = 0\.25: -?\d+\.\d ± \d+\.\d \(-?\d+\.\d% below clean\); p = 0\.5: ", printed,
                     re.M), printed
    with open(os.path.join(out, "report.md")) as file:
        report = file.read()
    assert f"| x | 0 | {worth['values'][0]:.1f} ± {worth['ci95_starts'][0]:.1f} | " in report
    failing = record["dropout"][0]
    assert (f"| 0.25 | {failing['mean_hidden']:.1f} | {failing['score']:.1f} ± {failing['ci95']:.1f} | "
            f"{100 * (record['clean_score'] - failing['score']) / abs(record['clean_score']):.1f}% |") in report
    assert re.search(r"^shapley: [\w ]+ \(\d\) worth most: φ -?\d+\.\d ± \d+\.\d of v\(all\) − v\(none\) -?\d+\.\d; hidden alone "
                     r"it costs -?\d+\.\d \(exact\)$", printed, re.M), printed
    # Each set's gap above the worst of its size, paired episode by episode (the same 6 start
    # states), and the printed line's count of the sets not told apart from the worst.
    for k in ("1", "2"):
        ranked = sorted(record["sets"][k], key=lambda entry: entry["score"])
        gaps = record["gaps_to_worst"][k]
        assert gaps["paired"] and [gap["hidden"] for gap in gaps["gaps"]] == [entry["hidden"] for entry in ranked[1:]]
        for gap, entry in zip(gaps["gaps"], ranked[1:]):
            difference = np.subtract(entry["returns"], ranked[0]["returns"])
            assert (gap["gap"], gap["ci95"]) == pytest.approx((difference.mean(), 2.5706 * difference.std(ddof=1) / np.sqrt(6)), rel=1e-4)
            assert gap["tied"] == (gap["gap"] <= gap["ci95"])
        tied = sum(gap["tied"] for gap in gaps["gaps"])
        assert re.search(rf"^k={k}: worst .*; " + (rf"not told apart from {tied} other set\(s\)$" if tied else
                                                   "told apart from every other set$"), printed, re.M), printed
    pair = record["sets"]["2"][0]
    assert pair["hidden"] == [0, 1] and pair["names"] == ["x", "y"]
    returns = np.asarray(pair["returns"])
    half_width = 2.5706 * returns.std(ddof=1) / np.sqrt(6)  # Student's t, 5 degrees of freedom
    assert pair["ci95"] == pytest.approx(half_width, rel=1e-4)
    assert pair["drop_percent"] == pytest.approx(100 * (record["clean_score"] - pair["score"]) / record["clean_score"])

    # The report's table rows are the JSON's worst sets, in order, with the same numbers.
    with open(os.path.join(out, "report.md")) as file:
        report = file.read()
    assert f"{record['clean_score']:.1f} ± {record['clean_ci95']:.1f}" in report
    for k in ("1", "2"):
        worst = sorted(record["sets"][k], key=lambda entry: entry["score"])
        section = report.split(f"## k = {k}:")[1].split("##")[0]
        average = np.mean([entry["score"] for entry in record["sets"][k]])  # the average case, beside the worst
        assert f"Mean over all {len(worst)} sets (the average case, u drawn uniformly): {average:.1f}, " in section
        table = re.findall(r"^\| (\d+) \| ([^|]+) \| ([^|]+) \| ([-\d.]+) ± ([\d.]+) \| ([-\d.]+)% \| ([^|]+) \|$",
                           section, re.M)
        assert len(table) == len(worst)
        gaps = [None] + record["gaps_to_worst"][k]["gaps"]
        for (rank, names, _, score, ci, drop, above), entry, gap in zip(table, worst, gaps):
            assert names.strip() == ", ".join(entry["names"])
            assert (float(score), float(ci), float(drop)) == pytest.approx(
                (entry["score"], entry["ci95"], entry["drop_percent"]), abs=0.051)
            if gap is None:
                assert above == "—"
            else:  # one decimal, or two significant digits below 0.05
                shown = re.fullmatch(r"\+([\d.e-]+) ± ([\d.e-]+)", above).groups()
                assert [float(value) for value in shown] == pytest.approx([gap["gap"], gap["ci95"]], rel=0.05, abs=0.051)
                assert all(float(value) > 0 or gap[key] == 0 for value, key in zip(shown, ("gap", "ci95")))
    assert f"k=1: worst {', '.join(sorted(record['sets']['1'], key=lambda e: e['score'])[0]['names'])}" in printed

    # tell_apart: a pilot of 4 episodes per set (seed 4's start states) says how many would tell
    # the worst pair from the runner-up; the audit is then score_missingness's at that N from
    # seed 5's.
    chosen_out = tmp_path / "tell_apart"
    assert audit_main([short_run.run_dir, "k=2", "episodes=4", f"out={chosen_out}", "seed=4", "tell_apart=true"]) == 0
    chosen = json.loads((chosen_out / "audit.json").read_text())
    pairs = jnp.asarray(candidate_sets(4, 2))
    pilot = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(4), pairs, 4)
    worst, runner_up = np.asarray(pilot.returns)[np.argsort(pilot.scores)[:2]]
    needed = samples_to_separate(worst, runner_up, paired=True)
    assert chosen["pilot"] == {"episodes": 4, "seed": 4, "needed": {"2": needed}, "chosen": chosen["n_episodes"], "most": 1000}
    assert chosen["n_episodes"] == min(max(4, needed), 1000)
    direct = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(5), pairs, chosen["n_episodes"])
    np.testing.assert_allclose([entry["score"] for entry in chosen["sets"]["2"]], direct.scores, rtol=1e-5)
    assert f"N = {chosen['n_episodes']:,} was chosen by a pilot audit of 4 episodes per set" in (chosen_out / "report.md").read_text()

    # The critic's estimate instead: estimate_scores's numbers for the same checkpoint.
    critic_out = str(tmp_path / "critic")
    assert audit_main([short_run.run_dir, "k=1", "episodes=6", f"out={critic_out}", "seed=4", "score_estimator=critic"]) == 0
    with open(os.path.join(critic_out, "audit.json")) as file:
        critic_record = json.load(file)
    direct = estimate_scores(ENV, policy.trainer.policy, policy.actor_params, policy.trainer.critic_values,
                             policy.critic_params, jax.random.key(4), jnp.asarray(candidate_sets(4, 1)), 6)
    assert critic_record["estimator"] == "critic"
    np.testing.assert_allclose([entry["score"] for entry in critic_record["sets"]["1"]], direct.scores, rtol=1e-5)
    with open(os.path.join(critic_out, "report.md")) as file:
        assert "the `critic` estimate" in file.read()

    # search=beam ranked by the critic, finalists confirmed by rollout: score_missingness's numbers.
    beam_out = str(tmp_path / "beam")
    assert audit_main([short_run.run_dir, "k=2", "episodes=6", f"out={beam_out}", "seed=4", "search=beam",
                       "beam_width=2", "ranker=critic"]) == 0
    with open(os.path.join(beam_out, "audit.json")) as file:
        beam_record = json.load(file)
    finalists = np.zeros((2, 4), np.float32)
    for row, entry in zip(finalists, beam_record["sets"]["2"]):
        row[entry["hidden"]] = 1.0
    direct = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(4), finalists, 6)
    np.testing.assert_allclose([entry["score"] for entry in beam_record["sets"]["2"]], direct.scores, rtol=1e-5)
    assert beam_record["search"]["2"]["ranker"] == "critic" and beam_record["estimator"] == "rollout"
    assert sorted(os.listdir(beam_out)) == ["audit.json", "report.md"]
    with open(os.path.join(beam_out, "report.md")) as file:
        beam_report = file.read()
    assert "worst found by beam search" in beam_report and "Mean over" not in beam_report  # finalists: no average

    # Over training: every checkpoint kept (keep_checkpoints=3: 200, 400, 600) audited, each as a single audit of it.
    over = tmp_path / "over"
    assert audit_main([short_run.run_dir, "steps=all", "k=1,2", "episodes=6", "seed=4", f"out={over}", "shapley=6",
                       "dropout=0.5", "dropout_masks=4"]) == 0
    assert sorted(os.listdir(over)) == ["robustness_over_training.md", "robustness_over_training.png", "step200",
                                        "step400", "step600"]
    table = (over / "robustness_over_training.md").read_text()
    for step in (200, 400, 600):
        alone = json.loads((over / f"step{step}" / "audit.json").read_text())
        assert alone["source"]["checkpoint (env step)"] == step
        direct = score_missingness(ENV, policy.trainer.policy, load_policy(short_run.run_dir, step).actor_params,
                                   jax.random.key(4), jnp.asarray(candidate_sets(4, 2)), 6)
        np.testing.assert_allclose([entry["score"] for entry in alone["sets"]["2"]], direct.scores, rtol=1e-5)
        row = next(line for line in table.splitlines() if line.startswith(f"| {step} | "))
        assert f"| {float(np.mean(direct.scores)):.1f} |" in row  # k=2's mean a_u at that checkpoint
        worth = alone["shapley"]
        top = int(np.argmax(worth["values"]))  # the feature worth most at that checkpoint, and its φ
        failing = alone["dropout"][0]  # and R(0.5) then, under random sensor failure
        assert row.endswith(f"| {alone['feature_names'][top]}: {worth['values'][top]:.1f} ± {worth['ci95_starts'][top]:.1f} "
                            f"of {worth['full'] - worth['blind']:.1f} | {failing['score']:.1f} ± {failing['ci95']:.1f} |"), row
    assert "step 200: k=1: worst" in capsys.readouterr().out

    # The best policy: the networks of the scoring with the highest min_u a_u, kept beside the
    # records (here also in a checkpoint, as every one is kept); best=true audits it, into a
    # folder named for it, with the same numbers as the audit of that checkpoint above.
    trained = [row for row in short_run.scores if row["env_steps"] > short_run.config.learning_starts]  # not 200's
    best_row = max(trained, key=lambda row: row["min_score"])
    best = load_policy(short_run.run_dir, "best")
    assert (best.step, best.best_min_score) == (best_row["env_steps"], best_row["min_score"])
    saved = load_policy(short_run.run_dir, best.step)
    for kept, checkpointed in zip(jax.tree.leaves((best.actor_params, best.critic_params)),
                                  jax.tree.leaves((saved.actor_params, saved.critic_params))):
        np.testing.assert_array_equal(kept, checkpointed)
    assert audit_main([short_run.run_dir, "best=true", "k=1,2", "episodes=6", "seed=4"]) == 0
    best_out = os.path.join(short_run.run_dir, f"audit-best-step{best.step}")
    best_record = json.loads(open(os.path.join(best_out, "audit.json")).read())
    shutil.rmtree(best_out)
    assert best_record["source"]["kept as"] == f"its best scoring (training's min_u a_u {best_row['min_score']:.1f})"
    assert best_record["sets"] == json.loads((over / f"step{best.step}" / "audit.json").read_text())["sets"]
    assert f"auditing the best policy (env step {best.step}) of point_mass" in capsys.readouterr().err

    # Sensors that fail at env step 3 of the 12: score_missingness's numbers with fail_at=3, in
    # folders named for it, the latest checkpoint's and (steps=) over training.
    assert audit_main([short_run.run_dir, "k=1", "episodes=6", "seed=4", "fail_at=3"]) == 0
    assert audit_main([short_run.run_dir, "k=1", "episodes=6", "seed=4", "fail_at=3", f"steps={policy.step}"]) == 0
    late_out = os.path.join(short_run.run_dir, f"audit-step{policy.step}-fail3")
    late = json.loads(open(os.path.join(late_out, "audit.json")).read())
    over_late = os.path.join(short_run.run_dir, "audit-over-training-fail3")
    assert late == json.loads(open(os.path.join(over_late, f"step{policy.step}", "audit.json")).read())
    assert "(N = 6 episodes per set, `rollout`, sensors failing at env step 3)" in open(
        os.path.join(over_late, "robustness_over_training.md")).read()
    # ...and at steps 3 and 6 in one command: each as audited alone, then the page of both.
    assert audit_main([short_run.run_dir, "k=1", "episodes=6", "seed=4", "fail_at=6,3"]) == 0
    times = os.path.join(short_run.run_dir, "audit-failure-times")
    assert sorted(os.listdir(times)) == ["fail3", "fail6", "failure_times.md", "failure_times.png"]
    assert json.loads(open(os.path.join(times, "fail3", "audit.json")).read()) == late
    ended = sum(length <= 3 for length in late["clean_lengths"])  # clean episodes over by step 3
    table = open(os.path.join(times, "failure_times.md")).read()
    assert f"\n| 3 ({ended} of 6) | {late['clean_score']:.1f} ± " in table
    assert "(N = 6 episodes per set, `rollout`): per k" in table  # (each row's own step, not the first's for all)
    shutil.rmtree(late_out), shutil.rmtree(over_late), shutil.rmtree(times)
    direct = score_missingness(ENV, policy.trainer.policy, policy.actor_params, jax.random.key(4),
                               jnp.asarray(candidate_sets(4, 1)), 6, fail_at=3)
    np.testing.assert_allclose([entry["score"] for entry in late["sets"]["1"]], direct.scores, rtol=1e-5)
    assert late["fail_at"] == 3 and late["clean_lengths"] == np.asarray(direct.lengths[-1]).tolist()
    capsys.readouterr()  # (what these audits said)

    # Bad input: one line, exit status 2.
    for args, message in [(["steps=all", "step=200"], "steps= audits several checkpoints of one run"),
                          (["best=true", "step=200"], "best=true audits the policy a run kept at its best scoring"),
                          (["steps=300"], "no checkpoint at 300 in "), (["steps=two"], "steps must be 'all'"),
                          (["step=300", f"out={tmp_path / 'at300'}"], "no checkpoint 300 in "),
                          (["k=1", "episodes=20000", "shapley=exact", f"out={tmp_path / 'big'}"],  # 4 + 16 sets
                           "auditing k=1 on point_mass is 20 sets x 20000 episodes in one rollout, over 200,000: lower "
                           "episodes=, drop the largest k, use search=beam or give shapley= fewer feature orders"),
                          (["k=1,4", f"out={tmp_path / 'k4'}"], "k must be set sizes 1 <= k < d = 4, got 1, 4"),
                          (["fail_at=12"], "fail_at=12 is not below the episodes' 12 steps: nothing would fail"),
                          (["fail_at=2", "score_estimator=horizon"], "fail_at=2 needs rollouts: give score_estimator=rollout")]:
        try:
            status = audit_main([short_run.run_dir, *args])
        except SystemExit as exit_info:  # refused by the parser's validation
            status = exit_info.code
        said = capsys.readouterr()
        error = said.err.strip().splitlines()
        assert status == 2 and len(error) == 1 and error[0].startswith(f"error: {message}"), error
        assert "auditing" not in said.out, said.out  # refused before the audit starts
    # refused before the folder is made
    assert not (tmp_path / "big").exists() and not (tmp_path / "at300").exists() and not (tmp_path / "k4").exists()
    unsaved = tmp_path / "unsaved"  # a run folder copied without its checkpoints (or stopped before the first)
    unsaved.mkdir()
    shutil.copy(os.path.join(short_run.run_dir, "config.yaml"), unsaved)
    assert audit_main([str(unsaved), "k=1"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: {unsaved} has no checkpoints (no checkpoints/ and no experiment.yaml above it)")
    # The video refuses a run whose env Gymnasium has no twin of to render (this point-mass run is at hand).
    from admissable_jax import video

    assert video.main([short_run.run_dir, f"out={tmp_path / 'mass.mp4'}"]) == 2
    assert capsys.readouterr().err.strip() == "error: point_mass has no Gymnasium env to render"
    capsys.readouterr()  # (what the audits above said)
    with pytest.raises(SystemExit) as refused:  # a bad key stops the parser itself
        audit_main([short_run.run_dir, "k=0"])
    assert refused.value.code == 2
    assert audit_main([str(tmp_path / "nothing"), "k=1"]) == 2
    assert audit_main([short_run.run_dir, "k=1", "out=/dev/null/x"]) == 2  # found before the rollout
    errors = capsys.readouterr().err.strip().splitlines()
    assert errors == ["error: k must be a comma list of set sizes >= 1, got '0'",
                      f"error: {tmp_path / 'nothing'} is not a run directory (no config.yaml)",
                      "error: cannot create the audit folder /dev/null/x: Not a directory"]
