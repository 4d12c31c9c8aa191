"""The scores a_u of the candidate sets: the paper's rollout and cheaper estimates.

- :func:`score_missingness` (:mod:`.estimators`): every set's a_u by ``score_estimator``:

  - ``rollout`` (:mod:`.rollout_scores`): the paper's a_u, N whole episodes per set in one
    batched rollout; the default everywhere;
  - ``critic``, ``horizon`` (:func:`estimate_scores`, :mod:`.value_estimates`): the trained
    critic's discounted value, alone or after H physics steps.
- :func:`beam_search_worst_sets` (:mod:`.set_search`): the worst sets of k features by
  beam search, where C(d, k) sets are too many to score.
- :mod:`.worst_set`: is the worst set the worst? The gap between two sets' scores with its
  interval (paired where they share start states) and the episodes that would resolve it.
- :mod:`.attribution`: each feature's Shapley value in the missingness game.
- :mod:`.dropout`: the expected return when each feature fails independently with probability p.
"""

from admissable_jax.scoring.estimators import SCORE_ESTIMATORS, score_missingness
from admissable_jax.scoring.rollout_scores import MissingnessScores, PolicyFn
from admissable_jax.scoring.set_search import SearchResult, SetScorer, beam_search_worst_sets
from admissable_jax.scoring.value_estimates import CriticFn, estimate_scores

__all__ = ["SCORE_ESTIMATORS", "CriticFn", "MissingnessScores", "PolicyFn", "SearchResult", "SetScorer",
           "beam_search_worst_sets", "estimate_scores", "score_missingness"]
