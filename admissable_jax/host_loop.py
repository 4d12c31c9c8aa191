"""The host loop over scorings, for one run or a batch of (seed, mode) pairs.

It alternates two jitted functions: ``run_chunk`` (ζ env steps of SAC over the parallel
envs, on the device, in up to 10 calls so that the progress bar moves) and
``score_and_update`` (every u scored in one batched rollout, then the adversary's p_miss
update). After each scoring it appends one row to
``scores.jsonl`` and one to ``metrics.jsonl`` of every run directory, and every
``checkpoint_every`` scorings (and at the end) it saves an orbax checkpoint of the whole
training state, from which ``resume=true`` continues; ``fast_forward=true`` then re-trains
the intervals recorded after that checkpoint (or all of them, where there is none) without
scoring them (:mod:`admissable_jax.fast_forward`). Both functions are compiled before
the state is allocated, so a run that would not fit in memory stops before it starts.
A batch of pairs runs where its :class:`~admissable_jax.placement.PairPlacement` puts it
(one device or many, one process or many); this loop only asks it.
"""

from __future__ import annotations

import functools
import os
import shutil
import time
from typing import Any, Callable

import jax
import numpy as np
from tqdm.auto import tqdm

from admissable_jax.best_policy import KeptPolicy, write_best_policy
from admissable_jax.checkpointing import CheckpointError, Checkpoints
from admissable_jax.cli import in_background, progress_bar, report, reporting, stop_at_next_boundary, ticking
from admissable_jax.config import TrainConfig, curve_names, setting_warnings
from admissable_jax.envs import make_env
from admissable_jax.errors import Interrupted, RunFailed
from admissable_jax.fast_forward import RecordedScoring, check_fingerprint, recorded_rows, recorded_scorings
from admissable_jax.memory import MemoryBudget, MemoryBudgetExceeded, memory_budget
from admissable_jax.placement import PairPlacement
from admissable_jax.provenance import invocation_record
from admissable_jax.run_directory import PACE_INTERVALS, RunDirectory, metrics_row, score_row, trained_at
from admissable_jax.run_spec import RunSpec
from admissable_jax.training import Trainer, TrainState


class TrainingDiverged(RunFailed):
    """A loss became NaN or infinite; the last checkpoint is kept."""


class PhysicsCapacityExceeded(RunFailed):
    """The env's physics ran out of a fixed-size buffer; the last checkpoint is kept."""


def init_arguments(config: TrainConfig) -> tuple[int, bool, bool, float, bool]:
    """What :meth:`Trainer.init` takes for a run, the parts of it that are data and not code:
    (seed, adversarial, masking, lower bound l, greedy)."""
    mode = config.missingness
    return config.seed, mode in ("adversarial", "worst"), mode != "none", config.lower_bound, mode == "worst"


def stacked_init_arguments(pairs: list[TrainConfig]) -> tuple[np.ndarray, ...]:
    """:func:`init_arguments` of every pair, each stacked along the pair axis (a vmapped
    :meth:`Trainer.init` takes them)."""
    dtypes = (np.int32, bool, bool, np.float32, bool)
    return tuple(np.array(column, dtype) for column, dtype in zip(zip(*map(init_arguments, pairs)), dtypes))


def pairs_init(trainer: Trainer, pairs: list[TrainConfig], placement: PairPlacement) -> Callable[[], TrainState]:
    """The pairs' fresh training state, stacked along the pair axis where ``placement`` puts
    it (:meth:`Trainer.init <admissable_jax.training.Trainer.init>` of each pair's seed, mode and l)."""
    arguments = [placement.place(column) for column in stacked_init_arguments(pairs)]
    spread_init = jax.jit(placement.spread(trainer.init), out_shardings=placement.sharding)
    return lambda: spread_init(*arguments)


def make_trainer(config: TrainConfig, num_runs: int = 1) -> Trainer:
    """The env and the trainer for a resolved config, sized for ``num_runs`` vmapped runs
    on one device."""
    spec = RunSpec.of(config, num_runs)
    return Trainer(make_env(spec.env, spec.env_options), spec)


MAX_PIECES = 10


def interval_pieces(iterations: int) -> int:
    """Into how many jitted calls a scoring interval's ``iterations`` are cut, so that the
    progress bar moves within an interval (on a CPU one takes minutes): the largest divisor
    of ``iterations`` up to 10. The calls are queued at once, so the device never waits on
    the host between them; the iterations they run are the same as in one call."""
    return max(pieces for pieces in range(1, MAX_PIECES + 1) if iterations % pieces == 0)


def queue_pieces(run_piece: Callable[[TrainState], tuple[TrainState, Any]], state: TrainState,
                 pieces: int) -> tuple[TrainState, list[Any]]:
    """``pieces`` calls of ``run_piece`` from ``state``, each queued without waiting for the
    one before: the state after the last, and each call's metrics (still on the device)."""
    piece_metrics = []
    for _ in range(pieces):
        state, metrics = run_piece(state)
        piece_metrics.append(metrics)
    return state, piece_metrics


def failure_lines(spec: RunSpec) -> list[str]:
    """The opening lines of a run whose sensors fail mid-episode (``fail_at``,
    ``score_fail_at``): when u is hidden in training and in scoring; none for the paper's
    u, hidden from the start in both."""
    def steps_text(steps: tuple[int, ...], how: str) -> str:
        return f"{', '.join(map(str, steps[:-1]))} or {steps[-1]} ({how})" if len(steps) > 1 else str(steps[0])

    if spec.fail_steps == spec.score_fail_steps == (0,):
        return []
    scoring = ("scoring hides u from the start" if spec.score_fail_steps == (0,) else
               f"scoring hides each set's u from env step {steps_text(spec.score_fail_steps, 'its N episodes split evenly')} on")
    if spec.fail_steps == (0,):
        return [f"sensors fail mid-episode in scoring: {scoring}, every feature seen before; training hides u from "
                "the start"]
    return [f"sensors fail mid-episode: each training episode hides its u from env step "
            f"{steps_text(spec.fail_steps, 'one drawn per episode')} on, every feature seen before; {scoring}"]


def take_pair(tree: Any, index: int) -> Any:
    """Run ``index``'s part of a pytree batched over runs (leading axis)."""
    return jax.tree.map(lambda leaf: leaf[index], tree)


def progress_postfix(rows: list[dict[str, Any]], curves: list[str]) -> dict[str, str]:
    """The progress bar's latest scores: min_u a_u and the clean return, the mean over the
    runs; with several curves in one program (an experiment's modes, and the values of l in
    a sweep: :func:`~admissable_jax.config.curve_names`), min_u a_u per curve, so that they
    can be watched side by side."""
    mean = lambda key, picked: f"{np.mean([row[key] for row in picked]):.1f}"
    if len(set(curves)) == 1:
        return {"min_a_u": mean("min_score", rows), "clean": mean("clean_score", rows)}
    return {f"min_a_u_{curve}": mean("min_score", [row for row, of in zip(rows, curves) if of == curve])
            for curve in dict.fromkeys(curves)}


class TrainingLoop:
    """The host loop over scorings for one run or a batch of pairs.

    ``init()`` builds the training state: one run's, or with a ``placement`` the pairs'
    stacked along a leading axis that the placement spreads over its devices; the train
    chunk and the scoring round are the trainer's, run per pair where the placement says.
    ``runs`` are the directories of the pairs this process holds
    (``placement.local_pairs``), in that order.
    """

    def __init__(
        self,
        trainer: Trainer,
        config: TrainConfig,
        runs: list["RunDirectory"],
        checkpoints: Checkpoints,
        init: Callable[[], TrainState],
        placement: PairPlacement | None = None,
    ):
        self.trainer, self.config, self.runs, self.checkpoints = trainer, config, runs, checkpoints
        self.init, self.placement = init, placement
        self.num_runs = placement.num_pairs if placement else 1
        self.curves = curve_names([(run.config.missingness, run.config.lower_bound) for run in runs])
        self.num_devices = placement.num_devices if placement else 1
        self.pieces = interval_pieces(trainer.spec.iterations_per_scoring)
        run_piece = lambda state: trainer.run_chunk(state, trainer.spec.iterations_per_scoring // self.pieces)

        def score_and_update(state: TrainState):  # the round, and the fingerprint of the state it leaves
            state, scores = trainer.score_and_update(state)
            return state, scores, trainer.fingerprint(state)

        def recorded_round(state: TrainState, p_miss, pool):  # what a recorded round left, put in place
            state = trainer.after_scoring(state, p_miss, pool)
            return state, trainer.fingerprint(state)

        self._run_piece, self._score_and_update, self._recorded_round = run_piece, score_and_update, recorded_round

    def host_rows(self, tree: Any) -> Any:
        """A device pytree of the loop's on the host: this process's pairs along the leading
        axis (``runs`` order) with a placement, the tree itself for one run."""
        return self.placement.local_rows(tree) if self.placement else jax.device_get(tree)

    def select_pair(self, rows: Any, index: int) -> Any:
        """``runs[index]``'s part of ``host_rows``' result (the rows themselves for one run)."""
        return take_pair(rows, index) if self.placement else rows

    def any_process(self, flag: bool) -> bool:
        """Whether ``flag`` holds in any process of the job."""
        return self.placement.any_process(flag) if self.placement else bool(flag)

    def abstract_state(self) -> TrainState:
        """The state's shapes (and, with a placement, its sharding), nothing allocated."""
        shapes = jax.eval_shape(self.init)
        if not self.placement:
            return shapes
        sharding = self.placement.sharding
        return jax.tree.map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=sharding), shapes)

    def program(self, function: Callable[..., Any], in_turn: bool = False) -> Callable[..., Any]:
        """``function``, whose first argument and first result are the training state, jitted
        as the loop runs its programs: the state donated and, with a placement, each pair's
        part run on the device that holds it (``in_turn``: one pair after another, see
        :meth:`PairPlacement.spread`)."""
        return self.placement.jit(function, in_turn) if self.placement else jax.jit(function, donate_argnums=0)

    def compile(self) -> MemoryBudget:
        """Compile both programs without allocating the state; refuse if they won't fit."""
        abstract_state = self.abstract_state()
        env = self.trainer.env
        where = f"{self.config.env} ({env.physics_name} physics) on {jax.devices()[0].platform}"
        # Both programs are traced here, then compiled on two threads at once (XLA compiles
        # outside Python's lock, so on two or more cores the compiles overlap) while this
        # thread waits, where a Ctrl-C is heard at once.
        # The pairs train vmapped (each steps as many iterations), and score in turn where a
        # batched step costs each world's work (a round lasts until its last episode ends).
        lowered = [self.program(self._run_piece).lower(abstract_state),
                   self.program(self._score_and_update, in_turn=env.steps_cost_each_world).lower(abstract_state)]
        with reporting(f"compiling the training step and the scoring round for {where}"):
            compiling = [in_background(program.compile) for program in lowered]
            self.run_piece, self.score_and_update = [program.result() for program in compiling]
        budget = memory_budget(abstract_state, self.run_piece, self.score_and_update, self.num_devices)
        if budget.needed_bytes > budget.available_bytes:
            raise MemoryBudgetExceeded(
                f"does not fit: {budget.describe()}; use fewer pairs, fewer num_envs or a smaller buffer_size"
            )
        return budget

    def run(self) -> TrainState:
        """Train from scratch or from the checkpoint ``resume`` names, up to
        ``planned_steps``, or until ``time_limit`` would be passed (then it checkpoints and
        returns early; ``resume=true`` continues). Every invocation trains at least one
        scoring interval. With ``fast_forward`` the intervals recorded after the checkpoint
        (all, without one) are re-trained first, each round put in place from its record."""
        config = self.config
        started_run = time.perf_counter()
        resume_from = self._resume_from()
        if resume_from is not None and resume_from >= config.planned_steps:
            report(f"nothing left to train: the run reached {resume_from} of {config.planned_steps} env steps "
                   f"(raise total_steps to train further)")
            _, state = self._restore(self.abstract_state(), resume_from)
            self.checkpoints.close()
            return state
        for warning in setting_warnings(config):
            report(f"warning: {warning}")
        # Read before compiling, so that records which cannot be fast-forwarded cost no compile.
        recorded = self._recorded_scorings(resume_from or 0) if config.fast_forward else [[] for _ in self.runs]
        budget = self.compile()
        report(f"{self.num_runs} run(s) x {config.num_envs} envs of {config.env} on "
               f"{self.trainer.env.physics_name} physics: {budget.describe()}")
        for line in failure_lines(self.trainer.spec):
            report(line)
        if self.placement:
            report(self.placement.describe())
        self._check_disk(budget.state_bytes * self.num_devices)
        state = self.init()
        start_step = 0
        if resume_from is not None:
            start_step, state = self._restore(state, resume_from)
        num_scorings = config.planned_steps // config.score_every
        first_scoring = start_step // config.score_every
        first_scored = min(num_scorings, first_scoring + min(map(len, recorded)))  # the first round scored here
        records_kept_to = first_scored * config.score_every  # start_step, unless fast_forward re-trains further
        if config.fast_forward:
            then = "then training on" if first_scored < num_scorings else "the run ends there"
            report(f"fast-forward: re-training env steps {start_step} to {records_kept_to} from "
                   f"{'checkpoint ' + str(start_step) if resume_from is not None else 'the start'}, each scoring's "
                   f"p_miss read from the records; {then}")
        if resume_from is not None or config.fast_forward:
            for run in self.runs:
                for note in run.set_aside_rows_after(records_kept_to):
                    report(note)
        invocation = invocation_record(start_step, records_kept_to if config.fast_forward else None, budget.device,
                                       self.num_devices, self.trainer.env.physics_name, self.num_runs)
        bar = progress_bar("env steps", total=config.planned_steps, initial=start_step, unit="step",
                           disable=not config.progress, dynamic_ncols=True)
        # The rate (and the time left) at the pace of this command's last PACE_INTERVALS scored
        # intervals that trained SAC, training and scoring: '?' until one has run (cli.PacedProgress).
        bar.pace, trained_seconds = 0.0, []
        with stop_at_next_boundary("at the end of this scoring interval, with a checkpoint") as stop, ticking(bar):
            try:
                for scoring in range(first_scoring, num_scorings):
                    interval_started = started = time.perf_counter()
                    state, chunk_metrics = self.train_interval(state, bar)
                    train_seconds = time.perf_counter() - started
                    env_steps = config.score_every * (scoring + 1)
                    self._check_finite(chunk_metrics, env_steps)
                    self._check_physics(np.any(chunk_metrics["capacity_exceeded"]), env_steps)

                    if scoring < first_scored:
                        bar.set_description_str("fast-forward")
                        rows = []
                        state = self._put_recorded_round(state, [of_run[scoring - first_scoring] for of_run in recorded])
                    else:
                        bar.set_description_str("scoring")
                        state, rows = self._score_and_record(state, env_steps, chunk_metrics, train_seconds)

                    last = scoring == num_scorings - 1
                    now = time.perf_counter()
                    if rows and trained_at(rows[0], config):
                        trained_seconds.append(now - interval_started)
                        bar.pace = config.score_every / float(np.mean(trained_seconds[-PACE_INTERVALS:]))
                    pause = self.any_process(not last and config.time_limit > 0
                                             and now - started_run + (now - interval_started) > config.time_limit)
                    stopped = not last and self.any_process(stop.requested)  # Ctrl-C or SIGTERM, in any process
                    saving = (scoring + 1) % config.checkpoint_every == 0 or last or pause or stopped
                    if invocation is not None and (rows or saving):  # this command's first rows or checkpoint
                        for run in self.runs:
                            run.record_invocation(invocation)
                        invocation = None
                    if saving:
                        bar.set_description_str("saving")
                        self.checkpoints.save(env_steps, state)
                    bar.set_description_str("")
                    if rows:
                        bar.set_postfix(progress_postfix(rows, self.curves),
                                        train_sps=f"{config.score_every * self.num_runs / train_seconds:.0f}")
                    if stopped:
                        raise self._interrupted()
                    if pause:
                        report(f"paused at {env_steps} of {config.planned_steps} env steps: another scoring interval "
                               f"would pass time_limit={config.time_limit:g} s; {self._kept_checkpoint()}; "
                               f"continue with resume=true")
                        break
            except KeyboardInterrupt:
                raise self._interrupted() from None
            finally:
                bar.close()
                self.checkpoints.close()
        return state

    def train_interval(self, state: TrainState, bar: tqdm) -> tuple[TrainState, dict[str, np.ndarray]]:
        """One scoring interval of training (ζ env steps) as ``pieces`` calls, all queued
        before the first is waited for; ``bar`` advances as each finishes. Returns the state
        and every iteration's metrics, on the host (``host_rows``)."""
        bar.set_description_str("training")
        state, piece_metrics = queue_pieces(self.run_piece, state, self.pieces)
        for metrics in piece_metrics:
            jax.block_until_ready(metrics)
            bar.update(self.config.score_every // self.pieces)
        iteration_axis = 1 if self.placement else 0  # after the pair axis
        return state, jax.tree.map(lambda *pieces: np.concatenate(pieces, axis=iteration_axis),
                                   *[self.host_rows(metrics) for metrics in piece_metrics])

    def _score_and_record(self, state: TrainState, env_steps: int, chunk_metrics: dict[str, np.ndarray],
                          train_seconds: float) -> tuple[TrainState, list[dict]]:
        """The scoring round after an interval, and each run's rows of it appended to its
        ``scores.jsonl`` and ``metrics.jsonl``. Returns the state and the runs' score rows."""
        started = time.perf_counter()
        state, scores, fingerprint = self.score_and_update(state)
        scores, p_miss, pool, grad_steps, fingerprint = self.host_rows(
            (scores, state.p_miss, state.pool, state.grad_steps, fingerprint))
        self._check_physics(np.any(scores.capacity_exceeded), env_steps)
        score_seconds = time.perf_counter() - started
        rows = []
        for index, run in enumerate(self.runs):
            pick = lambda tree: self.select_pair(tree, index)
            rows.append(score_row(env_steps, pick(scores), pick(p_miss), np.asarray(self.trainer.scored_sets(pick(pool))),
                                  self.trainer.spec.score_estimator, listed=self.trainer.pooled,
                                  fail_steps=self.trainer.spec.score_fail_steps))
            run.append("scores.jsonl", rows[-1])
            run.append("metrics.jsonl", metrics_row(env_steps, int(pick(grad_steps)), pick(chunk_metrics), train_seconds,
                                                    score_seconds, self.config, self.num_runs, int(pick(fingerprint))))
        self._keep_best_policies(state, env_steps, rows)
        return state, rows

    def _keep_best_policies(self, state: TrainState, env_steps: int, rows: list[dict]) -> None:
        """Write the networks of each run whose scoring ``rows`` beat its earlier ones to its
        ``best_policy.npz``; fetched from the device only where one did."""
        improved = [index for index, (run, row) in enumerate(zip(self.runs, rows)) if run.beats_best(row)]
        if not improved:
            return
        actor, critic = self.host_rows((state.sac.actor_params, state.sac.critic_params))
        for index in improved:
            write_best_policy(self.runs[index].path, KeptPolicy(env_steps, rows[index]["min_score"],
                                                                self.select_pair(actor, index),
                                                                self.select_pair(critic, index)))

    def _recorded_scorings(self, start_step: int) -> list[list[RecordedScoring]]:
        """Each run's recorded rounds after ``start_step`` (:func:`~admissable_jax.fast_forward.recorded_scorings`),
        for ``fast_forward=true``; ValueError in one line where there is nothing to re-train
        or the pairs live in several processes."""
        if self.placement and jax.process_count() > 1:
            raise ValueError("fast_forward=true runs in one process: its pairs' records are read on one host")
        pooled_sets = self.trainer.sets if self.trainer.pooled else None
        recorded = [recorded_scorings(run, start_step, self.config.score_every, pooled_sets) for run in self.runs]
        if not min(map(len, recorded)):
            bare = next(run.path for run, of_run in zip(self.runs, recorded) if not of_run)
            raise ValueError(f"nothing to fast-forward: {bare} records no scoring with a state fingerprint after env "
                             f"step {start_step} (runs recorded before fast_forward existed have none); "
                             f"resume without fast_forward")
        return recorded

    @functools.cached_property
    def recorded_round(self) -> Callable[..., tuple[TrainState, Any]]:
        """The compiled program that puts a recorded round in place (fast-forward only)."""
        return self.program(self._recorded_round)

    def _put_recorded_round(self, state: TrainState, recorded: list[RecordedScoring]) -> TrainState:
        """``state`` as the recorded round (one per run) left it, its fingerprint checked
        against the record (:func:`~admissable_jax.fast_forward.check_fingerprint`)."""
        p_miss, pool = (np.stack([getattr(round_, name) for round_ in recorded]) for name in ("p_miss", "pool"))
        if self.placement:
            p_miss, pool = self.placement.place(p_miss), self.placement.place(pool)
        else:
            p_miss, pool = p_miss[0], pool[0]
        state, fingerprint = self.recorded_round(state, p_miss, pool)
        fingerprint = self.host_rows(fingerprint)
        for index, (run, round_) in enumerate(zip(self.runs, recorded)):
            check_fingerprint(run, round_, int(self.select_pair(fingerprint, index)))
        return state

    def _check_disk(self, state_bytes: int) -> None:
        """Warn at the start when the checkpoints kept (``keep_checkpoints``, each about the
        whole state) would not fit on their disk. The run still starts: a disk that fills
        costs the checkpoint being written, never the last intact one."""
        kept = min(self.config.keep_checkpoints, self.config.planned_steps // self.config.score_every)
        where = self.checkpoints.directory
        while not os.path.exists(where):
            where = os.path.dirname(where)
        free = shutil.disk_usage(where).free
        if kept * state_bytes > free:
            report(f"warning: keeping {kept} checkpoint(s) of about {state_bytes / 2**30:.2f} GiB each needs "
                   f"{kept * state_bytes / 2**30:.2f} GiB, and {free / 2**30:.2f} GiB are free for "
                   f"{self.checkpoints.directory}: lower keep_checkpoints or free space")

    def _restore(self, like: TrainState, step: int) -> tuple[int, TrainState]:
        """Checkpoint ``step`` shaped like ``like``. With a placement the checkpoint may come
        from another device count: its pair axis is padded or cut to this mesh's size and the
        padding slots filled again (the real pairs are the same: the experiment checks)."""
        if not self.placement:
            return self.checkpoints.restore(like, step)
        step, state = self.checkpoints.restore(like, step, resizable_leading_axis=True)
        return step, self.placement.refill_padding(state)

    def _resume_from(self) -> int | None:
        """The checkpoint step a resumed run continues from (None for a fresh run)."""
        config = self.config
        if not config.resume:
            return None  # a fresh run
        if self.checkpoints.latest_step() is None:
            if config.fast_forward and config.resume_step < 0:
                return None  # fast-forwarded from the start
            reached = 0 if config.fast_forward else \
                min(len(recorded_rows(run.path, 0, config.score_every)) for run in self.runs) * config.score_every
            if reached:
                raise CheckpointError(
                    f"no checkpoint to resume from in {self.checkpoints.directory}; the records reach env step "
                    f"{reached}: resume=true fast_forward=true rebuilds the run from them")
        return self.checkpoints.step_to_restore(None if config.resume_step < 0 else config.resume_step)

    def _kept_checkpoint(self) -> str:
        kept = self.checkpoints.latest_step()
        where = f"last checkpoint (step {kept}) kept" if kept is not None else "no checkpoint yet"
        return f"{where} in {self.checkpoints.directory}"

    def _interrupted(self) -> Interrupted:
        """What a stop by Ctrl-C or SIGTERM ends the run with: where it can resume from."""
        return Interrupted(f"{self._kept_checkpoint()}; {self._how_to_continue()}")

    def _how_to_continue(self) -> str:
        if self.checkpoints.latest_step() is None:
            return "nothing to resume from: run the same command again to start over"
        return "continue with resume=true"

    def _check_physics(self, exceeded: bool, env_steps: int) -> None:
        if self.any_process(exceeded):
            raise PhysicsCapacityExceeded(
                f"at env step {env_steps}: {self.trainer.env.capacity_message()}; {self._kept_checkpoint()}"
            )

    def _check_finite(self, chunk_metrics: dict[str, np.ndarray], env_steps: int) -> None:
        diverged = None
        for index, run in enumerate(self.runs):
            metrics = self.select_pair(chunk_metrics, index)
            learned = metrics["learned"].astype(bool)
            for name in ("critic_loss", "actor_loss", "alpha"):
                if diverged is None and not np.all(np.isfinite(metrics[name][learned])):
                    diverged = f"{name} became non-finite before env step {env_steps} in {run.path}"
        if self.any_process(diverged is not None):
            raise TrainingDiverged(f"{diverged or 'a pair of another process diverged'}; {self._kept_checkpoint()}")
