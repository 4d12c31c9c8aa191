"""The house's layering (README, Code layout): nothing imports upward, no import cycles, and
the pure core touches no files. Read from the sources (every import, a function's own
included), so it costs no JAX."""

from __future__ import annotations

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / "admissable_jax"

# Bottom first. A module may import from its own layer (without a cycle) and from those below.
LAYERS = [
    {"errors", "method", "cli", "provenance", "placement", "loggers", "locks", "memory", "checkpointing", "envs",
     "replay", "sac_losses", "wrappers", "branching", "fingerprints", "best_policy", "exported_policy"},  # the method, the physics, and helpers that know nothing of training
    {"missingness", "adversary"},
    {"agent", "scoring", "config", "run_spec"},
    {"training"},  # the pure core
    {"run_directory", "fast_forward", "host_loop", "results"},  # a run's files written, and read back
    {"train", "experiment", "policies", "plot", "audit", "video", "export", "rollout", "status", "__main__"},  # the entry points
]
FILE_KEEPERS = {"checkpointing", "run_directory", "host_loop", "locks", "loggers", "provenance", "cli", "best_policy"}
PURE = {"training", "missingness", "adversary", "agent", "sac_losses", "replay", "scoring", "method", "branching",
        "fingerprints"}


def imports_by_module() -> dict[str, set[str]]:
    """Each top-level module or package of ours (``envs`` for ``envs/ant.py``) -> ours it imports."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts == ("__init__",):
            continue  # the lazy public names
        package = (PACKAGE.name, *parts[:-1])  # what a relative import of this file starts from
        imported = graph.setdefault(parts[0], set())
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                module = ".".join((*package[: len(package) - node.level + 1], *(node.module or "").split("."))) \
                    if node.level else node.module
                targets = [f"{module.strip('.')}.{alias.name}" for alias in node.names]
            else:
                continue
            imported.update(filter(None, map(_ours, targets)))
    return {name: targets - {name} for name, targets in graph.items()}


def _ours(target: str) -> str | None:
    """The top-level module or package of ours that ``target`` (a dotted name) lies in, if any."""
    pieces = target.split(".")
    if pieces[0] != PACKAGE.name or len(pieces) < 2:
        return None
    return pieces[1] if (PACKAGE / pieces[1]).is_dir() or (PACKAGE / f"{pieces[1]}.py").is_file() else None


def _a_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle of ``graph`` (its modules, the first again at the end), or []."""
    done: set[str] = set()

    def visit(name: str, path: list[str]) -> list[str]:
        if name in path:
            return path[path.index(name):] + [name]
        if name in done:
            return []
        for target in sorted(graph[name]):
            found = visit(target, path + [name])
            if found:
                return found
        done.add(name)
        return []

    return next((found for name in sorted(graph) if (found := visit(name, []))), [])


def test_nothing_imports_upward_nor_in_a_cycle_and_the_core_keeps_no_files():
    graph = imports_by_module()
    layer_of = {name: index for index, layer in enumerate(LAYERS) for name in layer}
    unplaced = sorted(set(graph) - set(layer_of))
    assert not unplaced, f"place {unplaced} in a layer of tests/test_layers.py (and the README's Code layout)"
    upward = sorted(f"{name} -> {target}" for name, targets in graph.items() for target in targets
                    if layer_of[target] > layer_of[name])
    assert not upward, f"imports upward: {upward}"

    assert not _a_cycle(graph), f"an import cycle: {' -> '.join(_a_cycle(graph))}"
    keeping_files = sorted(f"{name} -> {target}" for name in PURE for target in graph[name] & FILE_KEEPERS)
    assert not keeping_files, f"the pure core imports what writes files: {keeping_files}"
