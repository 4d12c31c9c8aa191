"""A branch that stays a branch under ``jax.vmap``.

``jax.lax.cond`` with a batched predicate (one per vmapped member) becomes a select: every
member computes both branches. An experiment vmaps its (seed, mode) pairs, so its
``learning_starts`` branch would compute (and throw away) a full set of SAC updates in every
iteration before learning starts: measured on 2 cores, a vmapped Hopper iteration of 8 envs
then cost 80-85% of one that learns, 5-6x one that skips the updates
(``benchmarks/train_throughput.py before_learning=true``, ``benchmarks/NOTES.md``).
:func:`lazy_cond` branches on whether any member takes the expensive branch instead.
:func:`while_any` is a loop that stays one loop under ``vmap``: every member steps while any
runs, with no per-member select of the carry. Their batching rules' broadcast of unbatched
operands, :func:`broadcast_unbatched`, serves the physics' own ``custom_vmap`` too
(``envs.physics.in_one_flat_batch``).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap


def lazy_cond(predicate: jax.Array, true_fun: Callable[..., Any], false_fun: Callable[..., Any], *operands: Any) -> Any:
    """``jax.lax.cond(predicate, true_fun, false_fun, *operands)``, and under ``vmap`` with a
    batched predicate still a branch: ``true_fun`` runs (for every member) only when some
    member's predicate holds, and each member keeps ``true_fun``'s result only where its own
    holds, so the results equal ``lax.cond``'s member by member. Nested vmaps branch at every
    level. The branch functions must close over no traced values: pass them as ``operands``."""

    @custom_vmap
    def branch(predicate, *operands):
        return jax.lax.cond(predicate, true_fun, false_fun, *operands)

    @branch.def_vmap
    def branch_batched(axis_size: int, in_batched: list[Any], predicate, *operands):
        predicate_batched, *operands_batched = in_batched
        operands = broadcast_unbatched(axis_size, operands, tuple(operands_batched))
        true_batched, false_batched = jax.vmap(true_fun), jax.vmap(false_fun)
        if not predicate_batched:
            out = lazy_cond(predicate, true_batched, false_batched, *operands)
        else:
            def each_its_own(predicate, *operands):
                taken, skipped = true_batched(*operands), false_batched(*operands)
                per_member = lambda leaf: predicate.reshape(predicate.shape + (1,) * (jnp.ndim(leaf) - 1))
                return jax.tree.map(lambda t, s: jnp.where(per_member(t), t, s), taken, skipped)

            out = lazy_cond(jnp.any(predicate), each_its_own, lambda _, *operands: false_batched(*operands),
                            predicate, *operands)
        return out, jax.tree.map(lambda _: True, out)

    return branch(predicate, *operands)


def while_any(cond_fun: Callable[..., Any], body_fun: Callable[..., Any], init: Any, *operands: Any) -> Any:
    """``jax.lax.while_loop`` with ``cond_fun(carry, *operands)`` and ``body_fun(carry,
    *operands)``; under ``vmap`` with a batched condition, every member runs the body while
    any member's condition holds, its own included.

    JAX's batching of a ``while_loop`` instead keeps each member's old carry once its own
    condition fails: a select of every carry leaf after every body, which keeps the old carry
    alive across the body, so an in-place step inside (Warp's physics) is handed a copy of
    each leaf. For a body whose results stop changing once its member's condition fails (a
    scoring rollout's steps after its last episode ended), nothing else differs. Nested vmaps
    loop while any member of any level runs. ``operands`` are read-only inputs: the two
    functions must close over no traced values.
    """

    @custom_vmap
    def loop(init, *operands):
        return jax.lax.while_loop(lambda carry: cond_fun(carry, *operands), lambda carry: body_fun(carry, *operands), init)

    @loop.def_vmap
    def loop_batched(axis_size: int, in_batched: list[Any], init, *operands):
        init, *operands = broadcast_unbatched(axis_size, (init, *operands), tuple(in_batched))
        cond_each, body_each = jax.vmap(cond_fun), jax.vmap(body_fun)
        out = while_any(lambda carry, *operands: jnp.any(cond_each(carry, *operands)), body_each, init, *operands)
        return out, jax.tree.map(lambda _: True, out)

    return loop(init, *operands)


def broadcast_unbatched(axis_size: int, tree: Any, in_batched: Any) -> Any:
    """In a ``custom_vmap`` rule: every leaf of ``tree`` that came in unbatched (its
    ``in_batched`` flag False) broadcast along a new leading batch axis of ``axis_size``."""
    return jax.tree.map(lambda leaf, batched: leaf if batched else jnp.broadcast_to(leaf, (axis_size, *jnp.shape(leaf))),
                        tree, in_batched)
