"""Test session set-up: JAX on the CPU, with a persistent compilation cache outside the repo.

MJX functions take tens of seconds to compile on a small CPU, so every compiled function
is built once per module by a fixture and shared by the tests that need it, and
pytest-xdist runs whole test files on every core (pyproject.toml). The most expensive
files go first, so that the workers finish together.
"""

import gc
import os
import sys

from admissable_jax import default_xla_flag  # the package's __init__ imports no JAX

# Tests import benchmark scripts by name (campaign, figure1, warp_kernels), as the scripts
# import their neighbour common.py.
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    os.path.join(os.path.expanduser("~"), ".cache", "admissable_jax", "jax_cache"),
)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
# Tests compile far more than they run: LLVM at -O0 compiles our MJX programs in about half
# the time and runs them up to 2x slower; the physics gives the same outputs, SAC runs differ
# by round-off (benchmarks/xla_cpu_compile.py, record xla_cpu_compile.jsonl). Subprocesses of
# the tests inherit it.
default_xla_flag("--xla_backend_optimization_level=0")
os.environ.setdefault("MUJOCO_GL", "egl")  # the video test renders headless (Mesa's EGL on a CPU)


# Longest first, as measured cold on 2 cores (a file's tests summed, --durations=0, 2026-12-03:
# 186 s down to 12 s); the rest take seconds. Each worker takes the next file as it nears the
# end of its own, so the two finish together: 6 s apart in a cold run of 380 s (in the order
# before, which ran test_sharding.py's 72 s near the end, 390 s and 358 s simulated).
EXPENSIVE_FIRST = ("test_hopper_pipelines.py", "test_envs.py", "test_training.py", "test_sharding.py",
                   "test_experiment.py", "test_runs.py", "test_plots.py", "test_audit.py",
                   "test_external_env.py", "test_figure1.py", "test_mechanism.py")


def pytest_collection_modifyitems(items):
    rank = {name: position for position, name in enumerate(EXPENSIVE_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_unconfigure(config):
    """Each process's session is over: freeze every object, so that the interpreter's closing
    garbage collections skip them, as a command's exit does (``cli.exit_with``). A worker that
    compiled MJX programs ended 2-3 s sooner on a 2-core CPU (the same files, 3 runs each way)."""
    gc.freeze()
