"""Test session set-up: JAX on the CPU, with a persistent compilation cache outside the repo.

MJX functions take tens of seconds to compile on a small CPU, so every compiled function
is built once per session by a fixture and shared by the tests that need it.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    os.path.join(os.path.expanduser("~"), ".cache", "admissable_jax", "jax_cache"),
)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
