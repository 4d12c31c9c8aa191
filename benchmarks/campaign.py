"""The GPU campaign's speed table and run plans (``benchmarks/gpu_campaign.sh`` calls these).

    python benchmarks/campaign.py measure env=hopper modes=adversarial,uniform,none seeds=5
    python benchmarks/campaign.py plan env=hopper modes=adversarial,uniform,none seeds=5 \\
        total_steps=1000000 deadline=690
    python benchmarks/campaign.py plan env=hopper modes=adversarial,uniform,none seeds=5 \\
        total_steps=1000000 fallback_modes=adversarial,uniform or_longest=true deadline=1650
    python benchmarks/campaign.py plan env=ant seeds=5 total_steps=0 min_steps=200000 deadline=690
    python benchmarks/campaign.py plan env=hopper modes=adversarial,uniform,none seeds=5 \\
        total_steps=1000000 or_longest=true records=runs/campaign/hopper deadline=790
    python benchmarks/campaign.py projections seeds=5 deadline=690   # all of the above
    python benchmarks/campaign.py profile env=hopper modes=adversarial,uniform,none seeds=5

``measure`` builds the experiment exactly as ``python -m admissable_jax.experiment`` would
for these settings (every (seed, mode) pair vmapped in one program) and times its parts on
this device: compiling both programs, one training chunk of ζ env steps with learning on,
one scoring round as it comes (untrained policy: short episodes), one scoring round in which
every episode runs its full ``episode_length`` (the env built with Gymnasium's
``terminate_when_unhealthy=False``: the longest a round can take, as late in training), and
saving and restoring the whole training state (replay buffers included) as a checkpoint.
It appends one record to ``campaign_speed.jsonl`` in the results folder. ``profile`` builds
the same programs and runs one training chunk (learning on) and one full-length scoring round
under JAX's profiler: per iteration of the chunk and per loop step of the round, the device's
busy and idle time, its ops, the costliest op kinds and the time by our programs' named
scopes (``profile_trace``; a ``campaign_profile`` record): where a latency-bound GPU loses
its time.

``plan`` reads the newest matching record (same env, envs per pair, physics and device;
the same number of pairs, else the fewest pairs above it: a program of fewer pairs does no
more work, so its time bounds the run's) and projects a run's wall time conservatively:
one compile, the first run's extra time (most likely Warp building its kernels), every scoring
round at full length, and a checkpoint save every
``checkpoint_every`` scorings and at the end. (The campaign runs each experiment in one
process that outlives the device calls following it, so nothing is restored or compiled
again per call.) It prints the projection and exits 0 if the run fits in ``deadline``
seconds, 3 if not. With ``total_steps=0`` it finds the longest run that fits (at least
``min_steps``, at most ``max_steps``). ``fallback_modes`` and ``or_longest`` say what to
try when the run does not fit, all in one process (the hopper step: the 15 pairs at 1M,
else the 10, else the longest run of the 15). The last line, ``modes=M total_steps=N``,
names the run chosen. With ``records=DIR`` the run continues the experiment in DIR, whose
runs' records came from another machine (``resume=true fast_forward=true``: the README's
*Fast-forward*): the intervals they recorded are re-trained first, each a chunk without its
scoring round, and only a run longer than the records is planned.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from typing import Any, Callable

import jax

from admissable_jax.checkpointing import Checkpoints
from admissable_jax.cli import enable_compilation_cache, parse_args, report
from admissable_jax.envs import env_spec, make_env, resolve_physics
from admissable_jax.config import EXPERIMENT_SETTINGS, ExperimentConfig, pair_configs
from admissable_jax.experiment import check_same_pairs
from admissable_jax.fast_forward import recorded_rows
from admissable_jax.host_loop import TrainingLoop, make_trainer, pairs_init, queue_pieces
from admissable_jax.placement import PairPlacement
from admissable_jax.training import Trainer
import profile_trace
from common import COMMITTED_RESULTS_DIR, RESULTS_DIR, append_record, environment_record, run_benchmark, timed

REFUSED = 3  # plan's exit status for a run that does not fit
ALL_MODES, PAIRED_MODES = "adversarial,uniform,none", "adversarial,uniform"


@dataclasses.dataclass
class MeasureConfig(ExperimentConfig):
    """An experiment's settings (as ``experiment`` takes them); nothing is trained."""


@dataclasses.dataclass
class PlanConfig(ExperimentConfig):
    deadline: float = dataclasses.field(default=1800.0, metadata={"help": "device seconds left for this run"})
    min_steps: int = dataclasses.field(default=200_000, metadata={"help": "with total_steps=0: refuse a run shorter than this"})
    max_steps: int = dataclasses.field(default=1_000_000, metadata={"help": "with total_steps=0: never plan more than this"})
    fallback_modes: str = dataclasses.field(default="", metadata={"help": "modes to run instead if modes do not fit at total_steps ('' = none)"})
    or_longest: bool = dataclasses.field(default=False, metadata={"help": "if nothing fits at total_steps, the longest run of modes (>= min_steps)"})
    speed_device: str = dataclasses.field(default="", metadata={"help": "plan from this device's speed records ('' = this device's), e.g. an H100's on an H200 that has none"})
    records: str = dataclasses.field(default="", metadata={"help": "an experiment directory the run continues from its records (fast_forward=true): its recorded intervals re-trained first, a chunk each ('' = a fresh run)"})


@dataclasses.dataclass
class ProfileConfig(ExperimentConfig):
    trace_dir: str = dataclasses.field(default="", metadata={"help": "keep the profiler's trace in this folder ('' = a temporary one, deleted)"})
    top: int = dataclasses.field(default=15, metadata={"help": "the costliest op kinds listed per part"})


@dataclasses.dataclass
class Programs:
    """An experiment's programs as its host loop compiles them, and its fresh state."""

    pairs: list
    trainer: Trainer
    loop: TrainingLoop
    state: Any
    compile_s: float
    score_full: Callable  # the scoring round on an env that never terminates: every round at full length

    def chunk(self, state):
        """One interval as the experiment trains it: its pieces queued at once."""
        state, piece_metrics = queue_pieces(self.loop.run_piece, state, self.loop.pieces)
        return state, jax.tree.map(lambda *parts: jax.numpy.concatenate(parts, axis=1), *piece_metrics)


def compile_programs(config: ExperimentConfig) -> Programs:
    """The experiment's own programs for these settings, compiled by its host loop (the state
    donated to each), so that the run that follows finds them in the compilation cache."""
    pairs = pair_configs(config)
    placement = PairPlacement.over(len(pairs), config.devices)
    trainer = make_trainer(pairs[0], num_runs=placement.pairs_per_device)
    loop = TrainingLoop(trainer, pairs[0], [], None, pairs_init(trainer, pairs, placement), placement)
    start = time.perf_counter()
    loop.compile()
    state = loop.init()
    compile_s = time.perf_counter() - start
    endless = Trainer(make_env(trainer.spec.env, dataclasses.replace(trainer.spec.env_options, terminate_when_unhealthy=False)),
                      trainer.spec)
    score_full = loop.program(endless.score_and_update).lower(state).compile()
    return Programs(pairs, trainer, loop, state, compile_s, score_full)


def measure(config: MeasureConfig) -> int:
    programs = compile_programs(config)
    pairs, trainer, chunk, compile_s = programs.pairs, programs.trainer, programs.chunk, programs.compile_s
    (state, _), first_chunk_s = timed(chunk, programs.state)  # learning starts within it
    (state, metrics), chunk_s = timed(chunk, state)
    (state, scores, _), score_s = timed(programs.loop.score_and_update, state)
    (state, full), score_full_s = timed(programs.score_full, state)
    with tempfile.TemporaryDirectory() as directory:
        checkpoints = Checkpoints(directory)
        _, save_s = timed(lambda: checkpoints.save(1, state))
        (_, state), restore_s = timed(lambda: checkpoints.restore(state, 1))
        checkpoints.close()
    first = pairs[0]
    record = {
        "env": trainer.env.gymnasium_id, "physics": trainer.env.physics_name, "pairs": len(pairs),
        "num_envs": first.num_envs, "score_envs": first.score_envs, "score_episodes": first.score_episodes,
        "episode_length": first.episode_length, "score_every": first.score_every, "buffer_size": first.buffer_size,
        "compile_s": round(compile_s, 2), "first_chunk_s": round(first_chunk_s, 3), "chunk_s": round(chunk_s, 3),
        "learned_share": float(metrics["learned"].mean()),
        "score_s": round(score_s, 3), "score_loop_steps": int(scores.loop_steps.max()),
        "score_full_s": round(score_full_s, 3), "score_full_loop_steps": int(full.loop_steps.max()),
        "checkpoint_save_s": round(save_s, 2), "checkpoint_restore_s": round(restore_s, 2),
    }
    append_record("campaign_speed", record)
    print(
        f"{record['env']} ({record['physics']}), {len(pairs)} pairs x {first.num_envs} envs: compile {compile_s:.1f} s; "
        f"chunk of {first.score_every} env steps per pair {chunk_s:.2f} s "
        f"({first.score_every * len(pairs) / chunk_s:,.0f} env steps/s in all); scoring round {score_s:.2f} s "
        f"({record['score_loop_steps']} loop steps), at full length {score_full_s:.2f} s "
        f"({record['score_full_loop_steps']} loop steps); checkpoint save {save_s:.1f} s, restore {restore_s:.1f} s"
    )
    return 0


CHUNK_PART, SCORING_PART = "campaign:chunk", "campaign:scoring"


def profile(config: ProfileConfig) -> int:
    """One training chunk (learning on) and one full-length scoring round of the experiment's
    own programs under JAX's profiler, after a warm-up of each: where the device's time goes
    (``profile_trace``). Appends a ``campaign_profile`` record."""
    if config.top < 1:
        raise ValueError(f"top must be >= 1, got {config.top}")
    programs = compile_programs(config)
    first = programs.pairs[0]
    state = programs.state
    # Warm-up, up to the first chunk that learns throughout: the one that starts at or past
    # learning_starts (each iteration learns once more env steps than that are collected).
    warm_chunks = max(1, math.ceil(first.learning_starts / first.score_every))
    report(f"warming up: {warm_chunks} chunk(s) of {first.score_every} env steps per pair and a full-length scoring "
           f"round, then both traced")
    for _ in range(warm_chunks):
        state, _ = programs.chunk(state)
    state, _ = jax.block_until_ready(programs.score_full(state))
    options = jax.profiler.ProfileOptions()
    options.python_tracer_level = 0  # the device's ops and our two annotations are what is read
    with tempfile.TemporaryDirectory() as scratch:
        folder = config.trace_dir or scratch
        with jax.profiler.trace(folder, profiler_options=options):
            with jax.profiler.TraceAnnotation(CHUNK_PART):
                state, metrics = jax.block_until_ready(programs.chunk(state))
            with jax.profiler.TraceAnnotation(SCORING_PART):
                state, full = jax.block_until_ready(programs.score_full(state))
        trace = profile_trace.read_profile(folder)
        where, ops = profile_trace.device_ops(trace)
        windows = {part: profile_trace.annotation(trace, part) for part in (CHUNK_PART, SCORING_PART)}
    iterations = first.score_every // first.num_envs
    parts = [profile_trace.summarize_part(ops, CHUNK_PART, windows[CHUNK_PART], iterations, config.top,
                                          profile_trace.op_sources(programs.loop.run_piece.as_text())),
             profile_trace.summarize_part(ops, SCORING_PART, windows[SCORING_PART], int(full.loop_steps.max()), config.top,
                                          profile_trace.op_sources(programs.score_full.as_text()))]
    record = {
        "env": programs.trainer.env.display_name, "physics": programs.trainer.env.physics_name,
        "pairs": len(programs.pairs), "num_envs": first.num_envs, "score_episodes": first.score_episodes,
        "score_every": first.score_every, "updates_per_iteration": programs.trainer.spec.updates_per_iteration,
        "chunk_learned_share": float(metrics["learned"].mean()), "ops_from": where, "parts": parts,
    }
    append_record("campaign_profile", record)
    print(f"{record['env']} ({record['physics']}), {len(programs.pairs)} pairs x {first.num_envs} envs; ops from {where}; "
          f"a step is an iteration of the chunk ({record['updates_per_iteration']} updates per pair) or a loop step "
          f"of the scoring round")
    for part in parts:
        print(profile_trace.describe(part))
    if not profile_trace.names_our_scopes(parts):
        print("warning: no op names a scope of ours: the programs came from a compilation cache that older code "
              "filled (metadata is no part of its key); for the time by source, run again with "
              "JAX_COMPILATION_CACHE_DIR set to an empty folder")
    return 0


def speed_record(config: ExperimentConfig) -> tuple[dict, int]:
    """(the newest ``campaign_speed`` record for this experiment's shape on this device, from
    this campaign's records or the committed ones: one of the same number of pairs, else one
    of the fewest pairs above it (an upper bound); and the experiment's number of pairs). The
    run's length does not matter (``total_steps=0``, "find the longest", is read as one
    scoring interval). Builds no env: planning needs no physics."""
    pairs = pair_configs(dataclasses.replace(config, total_steps=max(1, config.total_steps)))
    want = {"env": env_spec(pairs[0].env).gymnasium_id, "physics": resolve_physics(pairs[0].physics),
            "num_envs": pairs[0].num_envs, "score_episodes": pairs[0].score_episodes,
            "episode_length": pairs[0].episode_length, "score_every": pairs[0].score_every,
            "device": getattr(config, "speed_device", "") or environment_record()["device"]}
    paths = [os.path.join(folder, "campaign_speed.jsonl") for folder in dict.fromkeys([COMMITTED_RESULTS_DIR, RESULTS_DIR])]
    records = []
    for path in filter(os.path.exists, paths):
        with open(path) as file:
            records += [json.loads(line) for line in file if line.strip()]
    same_shape = [r for r in records if r["pairs"] >= len(pairs)
                  and all(r.get(key) == value for key, value in want.items() if key != "device")]
    shaped = [r for r in same_shape if r.get("device") == want["device"]]
    if not shaped:
        # A lease on another chip (an H200 where only an H100 was measured): name the devices
        # that were, so the next call can plan from one of them instead of failing again.
        elsewhere = sorted({r["device"] for r in same_shape})
        advice = (f"the same shape was measured on {', '.join(elsewhere)}: plan from it with speed_device= "
                  f"(gpu_campaign.sh: CAMPAIGN_SPEED_DEVICE=)" if elsewhere else "run the campaign's speed step first")
        raise ValueError(f"no speed record in {' or '.join(paths)} for {dict(want, pairs=len(pairs))} (or more pairs): {advice}")
    fewest = min(r["pairs"] for r in shaped)
    return [r for r in shaped if r["pairs"] == fewest][-1], len(pairs)


@dataclasses.dataclass(frozen=True)
class Projection:
    scorings: int  # the run's scoring intervals, those re-trained from records included
    retrained: int  # of them, the intervals re-trained from records (a chunk each, no scoring round)
    saves: int
    total_s: float

    def describe(self, record: dict) -> str:
        retrained = (f"{_count(self.retrained, 'recorded interval')} re-trained x chunk {record['chunk_s']:.1f} s + "
                     if self.retrained else "")
        return (f"compile {record['compile_s']:.0f} s + first run {first_run_s(record):.0f} s + {retrained}"
                f"{_count(self.scorings - self.retrained, 'scoring')} x (chunk {record['chunk_s']:.1f} s + "
                f"full-length scoring {record['score_full_s']:.1f} s) + {_count(self.saves, 'checkpoint save')} x "
                f"{record['checkpoint_save_s']:.1f} s = {self.total_s:,.0f} s ({self.total_s / 60:.1f} min)")


def _count(number: int, noun: str) -> str:
    """'1 scoring', '156 scorings'."""
    return f"{number:,} {noun}{'s' * (number != 1)}"


def first_run_s(record: dict) -> float:
    """What a program's first run costs beyond a later one (the H100's first Hopper chunk:
    60.1 s against 2.2; most likely MuJoCo Warp building its kernels on a fresh machine)."""
    return max(0.0, record["first_chunk_s"] - record["chunk_s"])


def project(record: dict, scorings: int, checkpoint_every: int, retrained: int = 0) -> Projection:
    """Conservative wall time of a run of ``scorings`` scoring intervals in one process, the
    first ``retrained`` of them re-trained from records (fast-forward: no scoring round)."""
    saves = math.ceil(scorings / checkpoint_every)  # every checkpoint_every scorings, and at the end
    once = record["compile_s"] + first_run_s(record)
    total = (once + scorings * record["chunk_s"] + (scorings - retrained) * record["score_full_s"]
             + saves * record["checkpoint_save_s"])
    return Projection(scorings, retrained, saves, total)


def recorded_intervals(config: PlanConfig) -> int:
    """The scoring intervals a run continuing ``config.records`` re-trains: as far as every
    one of its pairs recorded them with a state fingerprint (0 for a fresh run). ValueError
    in one line where the records hold other pairs, or nothing to continue."""
    if not config.records:
        return 0
    pairs = pair_configs(dataclasses.replace(config, out=config.records, total_steps=max(1, config.total_steps)))
    check_same_pairs(config, pairs, os.path.join(config.records, EXPERIMENT_SETTINGS))
    scorings = min(len(recorded_rows(pair.out, 0, config.score_every)) for pair in pairs)
    if not scorings:
        raise ValueError(f"nothing to continue in {config.records}: a run there records no scoring with a state "
                         f"fingerprint")
    return scorings


def _shape(config: ExperimentConfig) -> tuple[str, dict]:
    """(the run's shape in words, its speed record)."""
    record, pairs = speed_record(config)
    timed_with = "" if record["pairs"] == pairs else f", timed with {record['pairs']} (an upper bound)"
    return (f"{record['env']}, {pairs} pairs x {record['num_envs']} envs{timed_with} "
            f"({record['physics']} on {record['device']})"), record


def _fits(config: PlanConfig, retrained: int) -> bool:
    """Whether a run of ``total_steps`` fits in ``deadline`` (and, continuing records whose
    first ``retrained`` intervals it re-trains, goes past them); its projection printed."""
    shape, record = _shape(config)
    scorings = math.ceil(config.total_steps / config.score_every)
    if scorings <= retrained:
        print(_nothing_to_add(config, retrained, f"total_steps={config.total_steps:,}"))
        return False
    projection = project(record, scorings, config.checkpoint_every, retrained)
    fits = projection.total_s <= config.deadline
    print(f"projected wall time for {shape}, {scorings * config.score_every:,} env steps: "
          f"{projection.describe(record)}; device time left {config.deadline:,.0f} s: "
          f"{'fits' if fits else 'does not fit, refused'}")
    return fits


def _longest(config: PlanConfig, retrained: int) -> int | None:
    """The most env steps (min_steps to max_steps; continuing records whose first
    ``retrained`` intervals it re-trains, past them) a run fits in ``deadline``, or None."""
    shape, record = _shape(config)
    scorings, most = retrained + 1, max(1, config.max_steps // config.score_every)
    if scorings > most:
        print(_nothing_to_add(config, retrained, f"max_steps={config.max_steps:,}"))
        return None
    fits = lambda scorings: project(record, scorings, config.checkpoint_every, retrained).total_s <= config.deadline
    while scorings < most and fits(scorings + 1):
        scorings += 1
    projection = project(record, scorings, config.checkpoint_every, retrained)
    steps = scorings * config.score_every
    if projection.total_s > config.deadline:
        print(f"no run of {shape} fits in {config.deadline:,.0f} s: {steps:,} env steps, the shortest, take "
              f"{projection.describe(record)}: refused")
        return None
    if steps < config.min_steps:
        print(f"the longest run of {shape} that fits in {config.deadline:,.0f} s is {steps:,} env steps "
              f"({projection.describe(record)}), below min_steps={config.min_steps:,}: refused")
        return None
    print(f"longest run of {shape} in {config.deadline:,.0f} s: {steps:,} env steps: {projection.describe(record)}")
    return steps


def _nothing_to_add(config: PlanConfig, retrained: int, limit: str) -> str:
    return (f"the records in {config.records} already reach {retrained * config.score_every:,} env steps: "
            f"nothing to add at {limit}, refused")


def plan(config: PlanConfig) -> int:
    """The run to start: ``modes`` at ``total_steps`` if it fits, else ``fallback_modes`` at
    ``total_steps``, else (``or_longest``) the longest run of ``modes``; with
    ``total_steps=0``, the longest run. Its last line ``modes=M total_steps=N`` names the run
    (exit 0); exit 3 if none fits."""
    if config.records and config.fallback_modes:
        raise ValueError("records= continues the pairs its runs hold: fallback_modes cannot change them")
    retrained = recorded_intervals(config)  # the records read once (0 for a fresh run)
    if config.total_steps > 0:
        for modes in filter(None, dict.fromkeys([config.modes, config.fallback_modes])):
            if _fits(dataclasses.replace(config, modes=modes), retrained):
                if modes != config.modes:
                    print(f"the {config.modes} pairs cannot finish in the time left; running the {modes} pairs")
                print(f"modes={modes} total_steps={config.total_steps}")
                return 0
        if not config.or_longest:
            return REFUSED
        print(f"{config.env} cannot reach {config.total_steps} env steps in {config.deadline:g} s: "
              f"the longest run that fits instead")
    steps = _longest(config, retrained)
    if steps is None:
        return REFUSED
    print(f"modes={config.modes} total_steps={steps}")
    return 0


def projections(config: PlanConfig) -> int:
    """The campaign's runs projected for one lease of ``deadline`` device seconds, each
    planned as its step will plan it (gpu_campaign.sh): Hopper and Walker2d with all 15
    pairs at ``total_steps``, else the 10 adversarial/uniform ones, else the longest run of
    the 15; the longest Ant run of the 10. The speed step ends with these. An env without a
    speed record is named and skipped."""
    fallback = "" if config.records else PAIRED_MODES  # a continuation keeps its pairs
    runs = [dataclasses.replace(config, env=env, modes=ALL_MODES, fallback_modes=fallback, or_longest=True)
            for env in ("hopper", "walker2d")]
    for run in runs + [dataclasses.replace(config, env="ant", modes=PAIRED_MODES, fallback_modes="", total_steps=0)]:
        try:
            plan(run)
        except ValueError as error:
            print(f"{run.env} ({run.modes}): not projected: {error}")
    return 0


VERBS = {"measure": (MeasureConfig, measure), "profile": (ProfileConfig, profile), "plan": (PlanConfig, plan),
         "projections": (PlanConfig, projections)}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in VERBS:
        print(f"usage: python benchmarks/campaign.py {'|'.join(VERBS)} key=value ... (--help after the verb)",
              file=sys.stderr)
        return 2
    verb, rest = argv[0], argv[1:]
    config_type, action = VERBS[verb]
    config = parse_args(config_type, rest, f"benchmarks/campaign.py {verb}", __doc__.splitlines()[0])
    if verb in ("measure", "profile"):
        enable_compilation_cache()  # as the experiment it measures: its programs then start the run compiled
    return action(config)


if __name__ == "__main__":
    run_benchmark(main)  # bad input (a ValueError): one line, exit 2
