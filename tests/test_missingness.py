"""Candidate sets, masking and the adversary's p_miss update (pure functions, no physics)."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from admissable_jax.adversary import inverse_score_p_miss, update_p_miss, uniform_p_miss
from admissable_jax.method import check_exact_size
from admissable_jax.missingness import (
    SetNumbering,
    candidate_sets,
    describe_set,
    mask_observation,
    num_candidate_sets,
    sample_distinct_sets,
    sample_set_indices,
)


def test_candidate_sets():
    singles = candidate_sets(5)
    np.testing.assert_array_equal(singles, np.eye(5, dtype=np.float32))
    pairs = candidate_sets(5, k=2, include_empty=True)
    assert pairs.shape == (1 + math.comb(5, 2), 5)
    assert pairs[0].sum() == 0 and (pairs[1:].sum(axis=1) == 2).all()
    assert len({tuple(row) for row in pairs}) == len(pairs)
    assert describe_set(pairs[1]) == "{0,1}" and describe_set(pairs[0]) == "{}"
    # The paper's U = {u : |u| <= k}: every set of 1 .. k features, smaller sets first.
    up_to_two = candidate_sets(5, k=2, up_to_k=True)
    np.testing.assert_array_equal(up_to_two, np.concatenate([singles, pairs[1:]]))
    assert num_candidate_sets(5, 2, include_empty=True, up_to_k=True) == 1 + 5 + 10
    np.testing.assert_array_equal(candidate_sets(5, up_to_k=True), singles)  # k = 1: the same U
    with pytest.raises(ValueError, match="k < d"):
        candidate_sets(11, k=11)
    with pytest.raises(ValueError, match="k < d"):
        candidate_sets(11, k=0)
    with pytest.raises(TypeError):
        candidate_sets(11, k=True)
    with pytest.raises(TypeError, match="^k must be an int, got float$"):  # a YAML "2.0" read as a float
        candidate_sets(11, k=2.0)
    with pytest.raises(TypeError, match=r"^num_features \(d\) must be an int, got str$"):
        candidate_sets("11", k=1)
    np.testing.assert_array_equal(candidate_sets(np.int64(11)), candidate_sets(11))  # d as NumPy gives it
    with pytest.raises(ValueError, match="exceed"):
        candidate_sets(105, k=4)
    assert check_exact_size(85, 3) == 98_770  # listed; with the smaller sets it is only numbered
    with pytest.raises(ValueError, match=r"C\(85, 1\) \+ ... \+ C\(85, 3\) = 102,425 candidate sets exceed the "
                                         r"100,000 that one batched rollout scores"):
        check_exact_size(85, 3, up_to_k=True)
    assert num_candidate_sets(85, 3, up_to_k=True) == 102_425
    with pytest.raises(ValueError, match="C\\(105, 9\\) = 3,005,047,770,725 candidate sets exceed the 2,147,483,647"):
        num_candidate_sets(105, 9)


def test_sample_distinct_sets_is_a_uniform_subset():
    """Floyd's draw (a pool's first sets where U is too big to list): distinct, in range,
    every index as likely as any other, in every position."""
    draws = np.asarray(jax.jit(jax.vmap(lambda key: sample_distinct_sets(key, 10, 4)))(
        jax.random.split(jax.random.key(0), 4_000)))
    assert draws.shape == (4_000, 4) and all(len(set(row)) == 4 for row in draws.tolist())
    assert draws.min() == 0 and draws.max() == 9
    for frequencies in (np.bincount(draws.ravel(), minlength=10) / draws.size, np.bincount(draws[:, 0], minlength=10) / 4_000):
        assert (np.abs(frequencies - 0.1) < 4 * np.sqrt(0.1 * 0.9 / 4_000)).all(), frequencies
    # Ant at k = 5: 96,560,646 sets, drawn from without listing or permuting them.
    assert len(set(np.asarray(sample_distinct_sets(jax.random.key(1), 96_560_646, 16)).tolist())) == 16


def _listed(d: int, k: int, include_empty: bool, up_to_k: bool) -> list[tuple[int, ...]]:
    """U's order written out: the empty set, then each size's sets in lexicographic order."""
    sizes = range(1, k + 1) if up_to_k else [k]
    return [()] * include_empty + [subset for size in sizes for subset in itertools.combinations(range(d), size)]


@pytest.mark.parametrize("d, k, include_empty, up_to_k", [(5, 1, False, False), (7, 3, True, True),
                                                          (9, 5, False, False), (11, 4, True, False)])
def test_set_numbering_is_us_order_both_ways(d, k, include_empty, up_to_k):
    """Index -> row and row -> index by arithmetic, in NumPy and under jit, against U listed."""
    numbering = SetNumbering(d, k, include_empty, up_to_k)
    listed = _listed(d, k, include_empty, up_to_k)
    computed = numbering._computed_rows(np.arange(numbering.count))
    assert numbering.count == len(listed) and [tuple(np.flatnonzero(row)) for row in computed] == listed
    np.testing.assert_array_equal(numbering.matrix, computed)
    np.testing.assert_array_equal(numbering.indices(computed), np.arange(len(listed)))
    if (d, k) == (7, 3):
        rows = jax.jit(numbering._computed_rows)(jnp.arange(numbering.count))
        np.testing.assert_array_equal(rows, computed)
        np.testing.assert_array_equal(jax.jit(numbering.indices)(rows), np.arange(len(listed)))


def test_set_numbering_numbers_a_u_too_big_to_list():
    """Ant at k = 3: 187,460 triples, never listed; spot checks against itertools' order."""
    numbering = SetNumbering(105, 3)
    with pytest.raises(ValueError, match="187,460 candidate sets exceed the 100,000"):
        numbering.matrix
    triples = list(itertools.combinations(range(105), 3))
    indices = np.array([0, 1, 104, 5_000, 123_456, 187_459])
    for rows in (numbering.rows(indices), np.asarray(jax.jit(numbering.rows)(jnp.asarray(indices)))):
        assert [tuple(np.flatnonzero(row)) for row in rows] == [triples[i] for i in indices]
    drawn = np.random.default_rng(0).integers(0, numbering.count, 2_000)
    np.testing.assert_array_equal(numbering.indices(numbering.rows(drawn)), drawn)


def test_mask_observation():
    obs = jnp.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    hidden = jnp.array([[0.0, 1.0, 0.0], [1.0, 0.0, 1.0]])
    np.testing.assert_array_equal(
        mask_observation(obs, hidden),
        [[1.0, 0.0, 3.0, 0.0, 1.0, 0.0], [0.0, 5.0, 0.0, 1.0, 0.0, 1.0]],
    )
    # A single row of u broadcasts over a batch; nothing hidden leaves obs and a zero indicator.
    np.testing.assert_array_equal(mask_observation(obs, jnp.zeros(3)), jnp.concatenate([obs, jnp.zeros((2, 3))], 1))
    # Rows of another d, or feature indices given for the row (which would broadcast to
    # nonsense: [2] to [2, 2, 2]), are refused in one line; under jit the values are not
    # known, and only the shape is checked.
    with pytest.raises(ValueError, match=r"hidden of shape \(4,\) does not broadcast to the observations' shape "
                                         r"\(2, 3\): give u's 0/1 row\(s\) of d = 3"):
        mask_observation(obs, jnp.zeros(4))
    with pytest.raises(ValueError, match=r"hidden must hold only 0 \(seen\) and 1 \(hidden\), got \[2.0\]; "
                                         r"admissable_jax.method.hidden_row\(indices, d\) makes the row of feature indices"):
        mask_observation(obs, jnp.array([2.0]))
    np.testing.assert_array_equal(jax.jit(mask_observation)(obs, hidden), mask_observation(obs, hidden))


def test_p_miss_update_against_hand_computed_values():
    scores = jnp.array([10.0, 20.0, -5.0, 40.0])
    eps = 1e-8
    # l = 0: -5 is clipped to 0 and gets nearly all the mass.
    weights = np.array([1 / (10 + eps), 1 / (20 + eps), 1 / eps, 1 / (40 + eps)])
    np.testing.assert_allclose(inverse_score_p_miss(scores, 0.0, eps), weights / weights.sum(), rtol=1e-6)
    # l = 5: 10 -> 1/5, 20 -> 1/15, -5 clipped to 5 -> 1/eps, 40 -> 1/35.
    weights = np.array([1 / (5 + eps), 1 / (15 + eps), 1 / eps, 1 / (35 + eps)])
    np.testing.assert_allclose(inverse_score_p_miss(scores, 5.0, eps), weights / weights.sum(), rtol=1e-6)
    # Positive scores, l = 0: p ∝ 1/a exactly.
    positive = jnp.array([1.0, 2.0, 4.0])
    np.testing.assert_allclose(inverse_score_p_miss(positive, 0.0, eps), [4 / 7, 2 / 7, 1 / 7], rtol=1e-6)

    # The same compiled, as training runs it (XLA once reassociated l away there: NaN).
    compiled = jax.jit(inverse_score_p_miss, static_argnums=(1, 2))
    np.testing.assert_allclose(compiled(scores, 5.0, eps), weights / weights.sum(), rtol=1e-6)

    uniform = uniform_p_miss(3)
    np.testing.assert_allclose(uniform, [1 / 3] * 3)
    yes, no = jnp.array(True), jnp.array(False)
    np.testing.assert_allclose(update_p_miss(uniform, positive, yes, no, 0.0, eps), [4 / 7, 2 / 7, 1 / 7], rtol=1e-6)
    np.testing.assert_array_equal(update_p_miss(uniform, positive, no, no, 0.0, eps), uniform)
    np.testing.assert_array_equal(update_p_miss(uniform, positive, yes, yes, 0.0, eps), [1.0, 0.0, 0.0])  # mode worst


def test_set_draws_follow_p_miss():
    p_miss = jnp.array([0.5, 0.3, 0.15, 0.05])
    draws = np.asarray(sample_set_indices(jax.random.key(0), p_miss, (40_000,)))
    frequencies = np.bincount(draws, minlength=4) / len(draws)
    # 4 standard errors of a binomial proportion at n = 40000.
    tolerance = 4 * np.sqrt(np.asarray(p_miss) * (1 - np.asarray(p_miss)) / len(draws))
    assert (np.abs(frequencies - np.asarray(p_miss)) < tolerance).all(), frequencies
