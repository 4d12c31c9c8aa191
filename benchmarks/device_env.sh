# Source on a lent GPU machine (no package index there): installs the carried wheels
# (.whl/, made with `pip download` for CPython 3.12) next to the image's own JAX/CUDA, puts
# this checkout on PYTHONPATH and keeps compiled programs in an ignored folder of the
# checkout (kept while the machine stays warm).
set -o pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || return 1
export PYTHONPATH=/tmp/site:$PWD:$PWD/benchmarks PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=$PWD/runs/jax_cache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=1
mkdir -p runs
python3 -c "import jax, mujoco, flax, optax, orbax.checkpoint as o, chex, brax; print('jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__, 'flax', flax.__version__, 'optax', optax.__version__, 'orbax', o.__version__, 'chex', chex.__version__, 'brax', brax.__version__)"
