"""Random sensor failure: the policy's expected return when each feature fails independently.

The paper's adversary picks the worst set u of at most k features. A sensor that fails by
wear or chance follows another law: each feature is lost with probability p, independently
of the others, for the whole episode (as u is), so that a policy meets every set, of every
size, with probability p^|u| (1 − p)^(d − |u|). The expected return under that law,

    R(p) = Σ_u p^|u| (1 − p)^(d − |u|) · a_u,

is what a deployment with a failure rate p can count on; where k = 1 training stops, R at
rates that hide several features at once shows how far its robustness carries.

R(p) is estimated from M masks drawn from that law per rate (a mask that hides nothing is
the clean case, one that hides everything is valued too), each valued as any hidden set is
(a_u, the mean return of N episodes; the audit values them in its one rollout beside its
sets): the mean of the M values, ± the 95% Student's t interval over the masks. NumPy only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from admissable_jax.scoring.worst_set import t_half_width


@dataclasses.dataclass(frozen=True)
class DropoutPlan:
    """The masks to value: ``masks`` per rate, drawn rate by rate."""

    rates: tuple[float, ...]
    masks: int  # M per rate
    hidden_rows: np.ndarray  # (len(rates) · M, d) float32 0/1, the first M of the first rate, ...


@dataclasses.dataclass
class DropoutScore:
    """R(p) at one failure rate p (module docstring)."""

    rate: float
    masks: int
    score: float  # the mean over the M masks of each mask's a_u
    ci95: float  # the 95% t interval's half-width over the masks
    mean_hidden: float  # features a mask hides, on average (≈ p · d)


def parse_rates(text: str) -> tuple[float, ...]:
    """``dropout=``'s failure rates, a comma list of probabilities in (0, 1]; () for none.
    ValueError in one line otherwise."""
    try:
        rates = tuple(sorted({float(part) for part in text.split(",") if part.strip()}))
    except ValueError:
        raise ValueError(f"dropout must be a comma list of failure rates in (0, 1], e.g. 0.05,0.1,0.2; got {text!r}") \
            from None
    if rates and not 0 < rates[0] <= rates[-1] <= 1:
        raise ValueError(f"dropout rates must lie in (0, 1], got {text!r}")
    return rates


def check_masks(masks: int) -> None:
    """ValueError in one line for fewer than 2 masks per rate, which give no interval."""
    if masks < 2:
        raise ValueError(f"dropout_masks must be at least 2 for an interval, got {masks}")


def plan_dropout(num_features: int, rates: tuple[float, ...], masks: int, seed: int) -> DropoutPlan | None:
    """M = ``masks`` masks per rate, each feature hidden with probability p, from ``seed``;
    None without rates."""
    if not rates:
        return None
    check_masks(masks)
    draws = np.random.default_rng(seed).random((len(rates), masks, num_features))
    hidden = draws < np.asarray(rates)[:, None, None]
    return DropoutPlan(tuple(rates), masks, hidden.reshape(-1, num_features).astype(np.float32))


def dropout_scores(plan: DropoutPlan, mask_scores: np.ndarray) -> list[DropoutScore]:
    """R(p) per rate of ``plan`` from each mask's a_u (``mask_scores``, in the plan's row order)."""
    per_rate = np.asarray(mask_scores, np.float64).reshape(len(plan.rates), plan.masks)
    hidden = plan.hidden_rows.reshape(len(plan.rates), plan.masks, -1).sum(axis=-1)
    return [DropoutScore(rate, plan.masks, float(values.mean()), float(t_half_width(values)), float(count.mean()))
            for rate, values, count in zip(plan.rates, per_rate, hidden)]
