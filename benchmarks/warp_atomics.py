"""Which of an env step's MuJoCo Warp kernels still use atomics outside Warp's RUN_TO_RUN mode.

    python benchmarks/warp_atomics.py env=hopper

A GPU run repeats bit for bit only if no kernel's result depends on the order in which the
GPU's threads arrive. Atomics are where it can: a float ``+=`` that several threads apply to
one element rounds differently in another order, and an ``atomic_add`` whose return value
is used (a slot counter: a contact's index, a constraint's rows) hands out slots in arrival
order. Warp's ``RUN_TO_RUN`` mode makes both order-free within a kernel; the deterministic
mode of ``envs/warp_package.py`` builds MuJoCo Warp's atomic kernels, its collision pass and
its constraint pass in it. This steps the env on the CPU (``steps`` random actions, then the
step it reads), then reads, for every kernel that step launched that is not built in that
mode, the C++ Warp generated for it (the CPU kernel cache), and lists each atomic reachable
from the kernel with the Python line it came from, as one of:

- ``slot counter``: the return value is used; order-dependent.
- ``float``: order-dependent where several threads update one element in one launch, not
  where each thread updates elements of its own (read the line).
- ``integer``: return value unused; integer sums are the same in any order.

Kernels launched over no threads (the model has none of what they loop over) are never
built, so nothing is read for them; they are counted apart. It prints the launches per env
step (all, and those in ``RUN_TO_RUN`` mode) and the list, and appends a record to
benchmarks/results/warp_atomics.jsonl.

It also counts what the mode adds on a GPU, where a ``RUN_TO_RUN`` kernel with atomics
takes Warp's deterministic launch path (on the CPU, which runs threads in order, Warp
launches it as any other): each atomic target of the forward launch is recorded, then
sorted and reduced (a *sort-reduce*: a CUB radix sort, a reduce by key and an apply
kernel), and each slot counter is scanned between two passes of the kernel. A kernel's
deterministic metadata also lists the targets of its adjoint (the gradients its backward
launch would sum into its inputs); a forward launch leaves those alone (Warp's
``launch_deterministic`` keeps the targets marked ``use_forward``), and the env step
launches no backward, so they are not counted. A latency-bound GPU pays for each of those
kernels as for a launch, so these counts against the launches per env step say what the
mode may cost there; only a GPU says what it does. Last, per kernel, the records per thread
Warp gives each slot counter there: a thread that calls it more often gets slot 0, unsaid
inside a CUDA graph (``EnvOptions.graph_mode``'s ``NONE`` checks it on a GPU).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import re

import jax
import jax.numpy as jnp

from admissable_jax.cli import parse_args
from admissable_jax.envs import canonical_env_name, make_env, warp_package
from common import append_record, run_benchmark
from warp_launches import launched_kernels

FUNCTION_HEAD = re.compile(r"^static (?:WP_FORCEINLINE |CUDA_CALLABLE )*[\w:<>, ]+?\b(\w+)\($", re.MULTILINE)
ATOMIC = re.compile(r"(?:(var_\w+) = )?wp::(atomic_\w+)\((var_\w+)")


@dataclasses.dataclass
class AtomicsConfig:
    env: str = dataclasses.field(default="hopper", metadata={"help": "hopper, walker2d, ant or halfcheetah"})
    num_envs: int = dataclasses.field(default=4, metadata={"help": "worlds stepped at once"})
    steps: int = dataclasses.field(default=30, metadata={"help": "random-action env steps before the step read (contacts, limits)"})
    deterministic: bool = dataclasses.field(default=True, metadata={"help": "MuJoCo Warp's deterministic mode (deterministic_physics)"})


def _validate(config: AtomicsConfig) -> None:
    if jax.default_backend() != "cpu":
        raise ValueError("warp_atomics.py reads the CPU kernels Warp generates; run it with JAX_PLATFORMS=cpu")
    canonical_env_name(config.env)
    if config.num_envs < 1 or config.steps < 0:
        raise ValueError(f"num_envs must be >= 1 and steps >= 0, got {config.num_envs} and {config.steps}")


def generated_source(warp, kernel) -> str:
    """The C++ Warp generated for ``kernel``'s module on the CPU, each block size's, from the kernel cache."""
    sources = []
    for _, block_dim in kernel.module.execs:
        folder = os.path.join(warp.config.kernel_cache_dir, kernel.module.get_module_identifier(block_dim))
        sources += [open(os.path.join(folder, name)).read() for name in sorted(os.listdir(folder)) if name.endswith(".cpp")]
    return "\n".join(sources)


def atomics_of(key: str, source: str) -> list[dict]:
    """The atomics reachable from kernel ``key``'s forward function in ``source``: each with its
    operation, kind (``slot counter``, ``float``, ``integer``) and the Python line it came from."""
    heads = list(FUNCTION_HEAD.finditer(source))
    functions = {head.group(1): source[head.start():(heads[i + 1].start() if i + 1 < len(heads) else len(source))]
                 for i, head in enumerate(heads)}
    (forward,) = [name for name in functions if re.fullmatch(rf"{re.escape(key)}_[0-9a-f]+_cpu_kernel_forward", name)]
    reached, pending = set(), [forward]
    while pending:
        name = pending.pop()
        reached.add(name)
        pending += [callee for callee in re.findall(r"\b(\w+)\(", functions[name])
                    if callee in functions and callee not in reached and not callee.startswith("adj_")]
    found = []
    for name in sorted(reached):
        body = functions[name]
        for match in ATOMIC.finditer(body):
            result, operation, target = match.groups()
            after = body[body.find("\n", match.end()):]
            declared = re.search(rf"^\s*wp::array_t<(.*)> {re.escape(target)}\b", body, re.MULTILINE)
            comments = [line.strip() for line in body[:match.start()].splitlines() if line.strip().startswith("//")]
            if result and re.search(rf"\b{re.escape(result)}\b", after):
                kind = "slot counter"
            elif declared is None or "float" in declared.group(1):
                kind = "float"
            else:
                kind = "integer"
            found.append({"operation": operation, "kind": kind,
                          "line": re.sub(r"\s+", " ", comments[-1][2:]).strip() if comments else ""})
    return found


def gpu_deterministic_path(kernels: dict, launches: collections.Counter, run_to_run: set) -> collections.Counter:
    """What the ``run_to_run`` kernels' forward launches add on a GPU: ``launches`` taking Warp's
    deterministic path, ``sort_reduces`` (one per forward atomic target and launch) and
    ``counter_scans`` (one per forward slot counter and launch). Adjoint targets are left out:
    only a backward launch reduces them."""
    added = collections.Counter({"launches": 0, "sort_reduces": 0, "counter_scans": 0})
    for key in run_to_run:
        meta = kernels[key].adj.det_meta
        if meta is not None and meta.needs_deterministic:
            added.update({"launches": launches[key],
                          "sort_reduces": launches[key] * sum(target.use_forward for target in meta.scatter_targets),
                          "counter_scans": launches[key] * sum(target.use_forward for target in meta.counter_targets)})
    return added


def slot_counter_records(kernels: dict, run_to_run: set) -> dict[str, dict[str, int]]:
    """Per ``run_to_run`` kernel with slot counters: the records per thread Warp gives each
    counter on a GPU (the atomic call sites in the kernel's code, or the module's
    ``deterministic_max_records``). A thread that calls a counter more often gets slot 0, and
    inside a CUDA graph nobody is told (``EnvOptions.graph_mode``'s ``NONE`` checks it), so
    compare these with the calls a thread can make, read in MuJoCo Warp's source."""
    records = {}
    for key in sorted(run_to_run):
        meta = kernels[key].adj.det_meta
        if meta is None:
            continue
        counters = {target.array_var_label: max(meta.counter_records_per_thread.get(target, 0), meta.max_records, 1)
                    for target in meta.counter_targets if target.use_forward}  # as Warp's allocate_counter_buffers
        if counters:
            records[key] = counters
    return records


def main(argv: list[str]) -> None:
    import warp

    config = parse_args(AtomicsConfig, argv, "benchmarks/warp_atomics.py", __doc__.splitlines()[0], _validate)
    env = make_env(config.env, physics="warp", max_batch=config.num_envs, deterministic=config.deterministic)
    step = jax.jit(jax.vmap(env.step))
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), config.num_envs))
    # Random actions first, so that the step read has feet on the floor and joints at their limits.
    for key in jax.random.split(jax.random.key(1), config.steps):
        states = step(states, jax.random.uniform(key, (config.num_envs, env.action_size),
                                                 minval=env.action_low, maxval=env.action_high))
    actions = jnp.zeros((config.num_envs, env.action_size))
    states = jax.block_until_ready(step(states, actions))  # compiled and run once (steps=0)
    kernels, launches, empty = launched_kernels(warp, step, states, actions)
    run_to_run = {key for key, kernel in kernels.items()
                  if kernel.module.options.get("deterministic") == warp.DeterministicMode.RUN_TO_RUN}
    launched_run_to_run = run_to_run - empty
    deterministic_path = gpu_deterministic_path(kernels, launches, launched_run_to_run)
    counter_records = slot_counter_records(kernels, launched_run_to_run)
    outside = {}
    for key in sorted(set(kernels) - run_to_run - empty):
        atomics = atomics_of(key, generated_source(warp, kernels[key]))
        if atomics:
            outside[key] = atomics
    record = {
        "env": env.gymnasium_id, "num_envs": config.num_envs, "steps_before": config.steps, "deterministic": config.deterministic,
        "mujoco_warp": warp_package.which(),
        "launches_per_env_step": sum(launches.values()),
        "run_to_run_launches": sum(launches[key] for key in run_to_run),
        "kernels": len(kernels), "run_to_run_kernels": len(run_to_run), "launched_over_no_threads": len(empty - run_to_run),
        "gpu_deterministic_path": {name: deterministic_path[name] for name in ("launches", "sort_reduces", "counter_scans")},
        "slot_counter_records_per_thread": counter_records,
        "atomics_outside_run_to_run": outside,
    }
    append_record("warp_atomics", record)
    print(f"{env.gymnasium_id} ({record['mujoco_warp']}, deterministic={config.deterministic}): "
          f"{record['launches_per_env_step']} launches per env step, {record['run_to_run_launches']} in RUN_TO_RUN "
          f"mode; {len(kernels)} kernels, {len(run_to_run)} in RUN_TO_RUN mode, "
          f"{record['launched_over_no_threads']} others launched over no threads")
    print(f"on a GPU, per env step: {deterministic_path['launches']} launches take Warp's deterministic path, "
          f"with {deterministic_path['sort_reduces']} sort-reduces and {deterministic_path['counter_scans']} counter scans")
    for key, counters in counter_records.items():
        print(f"  slot counters of {key}, records per thread: {counters}")
    kinds = collections.Counter(atomic["kind"] for atomics in outside.values() for atomic in atomics)
    print(f"atomics outside RUN_TO_RUN mode, in {len(outside)} kernels: {dict(kinds) or 'none'}")
    for key, atomics in outside.items():
        for atomic in atomics:
            print(f"  {key}: {atomic['kind']} ({atomic['operation']}): {atomic['line']}")


if __name__ == "__main__":
    run_benchmark(main)
