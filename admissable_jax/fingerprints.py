"""A 32-bit fingerprint of a pytree's exact bits, for telling whether two computations of a
training state agree bit for bit (a fast-forwarded run against the one that recorded it:
:mod:`admissable_jax.fast_forward`).

Every leaf's bits are read as uint32 words (floats bitcast, integers and bools widened),
the leaves' words joined in the tree's order, each word multiplied by an odd constant of its
position and summed modulo 2^32: an integer sum, so the result does not depend on the order
in which a device reduces it (a float sum would), and swapping two different values changes
it. 32 bits: two different states share a fingerprint with probability about 2^-32 per
comparison.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

_GOLDEN = 0x9E3779B1  # odd, so that multiplying by it permutes the uint32 words


def _words(leaf: jax.Array) -> jax.Array:
    """A leaf's bits as a flat uint32 vector."""
    leaf = jnp.asarray(leaf)
    if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.random.key_data(leaf)
    if leaf.dtype.itemsize == 4:
        return jax.lax.bitcast_convert_type(leaf, jnp.uint32).ravel()
    if jnp.issubdtype(leaf.dtype, jnp.floating):  # float16/bfloat16 and float64 alike: their float32 value
        return jax.lax.bitcast_convert_type(leaf.astype(jnp.float32), jnp.uint32).ravel()
    return leaf.astype(jnp.uint32).ravel()  # bools, small and 64-bit integers


def tree_fingerprint(tree: Any) -> jax.Array:
    """() uint32: the fingerprint of every leaf of ``tree`` (module docstring). Pure and
    jittable; vmap it for a batch of trees. The leaves' words are joined into one vector and
    summed at once: a reduction per leaf made XLA:CPU compile a training program's scoring
    round about 6 s longer."""
    words = jnp.concatenate([_words(leaf) for leaf in jax.tree.leaves(tree)] or [jnp.zeros((0,), jnp.uint32)])
    position = jnp.arange(words.size, dtype=jnp.uint32)
    return jnp.sum(words * (position * jnp.uint32(2) + jnp.uint32(1)) * jnp.uint32(_GOLDEN), dtype=jnp.uint32)
