"""The beam search for the worst sets alone, jitted, with a scorer that costs nothing.

    python benchmarks/set_search.py d=105 k=3 widths=16,105 repeats=3

The scorer is ``rows @ w`` (w fixed), so what is timed is the search's own work: each level
builds b · d candidates, keeps the first copy of each set among them, ranks them and keeps
the b lowest. The trainer's pool search (``pool_size`` = b, every scoring round) and the
audit's ``search=beam`` pay this on top of their scorer. Per width: compile seconds, the best
of ``repeats`` runs, XLA's temporaries and the sets ranked; one record per width appended to
``results/set_search.jsonl``.
"""

from __future__ import annotations

import dataclasses
import time

import jax

from admissable_jax.cli import check_at_least_one, parse_args
from admissable_jax.scoring import beam_search_worst_sets
from common import append_record, run_benchmark, timed


@dataclasses.dataclass
class SetSearchConfig:
    d: int = dataclasses.field(default=105, metadata={"help": "features (Ant: 105)"})
    k: int = dataclasses.field(default=3, metadata={"help": "features per set"})
    widths: str = dataclasses.field(default="16,105", metadata={"help": "comma list of beam widths b"})
    repeats: int = dataclasses.field(default=3, metadata={"help": "timed runs per width (the best is kept)"})


def _validate(bench: SetSearchConfig) -> None:
    check_at_least_one(bench, ("d", "k", "repeats"))  # (the search checks k <= d and each width)


def main(argv: list[str]) -> None:
    bench = parse_args(SetSearchConfig, argv, "benchmarks/set_search.py", __doc__.splitlines()[0], _validate)
    weights = jax.random.normal(jax.random.key(0), (bench.d,))
    for width in (int(text) for text in bench.widths.split(",")):
        search = jax.jit(lambda w: beam_search_worst_sets(lambda rows: rows @ w, bench.d, bench.k, width))
        start = time.perf_counter()
        compiled = search.lower(weights).compile()
        compile_s = time.perf_counter() - start
        result, _ = timed(compiled, weights)
        run_s = min(timed(compiled, weights)[1] for _ in range(bench.repeats))
        record = {
            "d": bench.d, "k": bench.k, "beam_width": width, "compile_s": round(compile_s, 2),
            "run_ms": round(1000 * run_s, 2), "temp_mib": round(compiled.memory_analysis().temp_size_in_bytes / 2**20, 1),
            "sets_ranked": int(result.num_ranked),
        }
        append_record("set_search", record)
        print(f"d = {bench.d}, k = {bench.k}, b = {width}: {record['sets_ranked']:,} sets ranked in {record['run_ms']} ms "
              f"(best of {bench.repeats}), temporaries {record['temp_mib']} MiB, compile {record['compile_s']} s")


if __name__ == "__main__":
    run_benchmark(main)
