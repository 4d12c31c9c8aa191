#!/usr/bin/env bash
# The GPU benchmark suite, as run on a lent H100 (device tool) from the repository root:
#   . benchmarks/device_env.sh && bash benchmarks/gpu_suite.sh
# Each step has its own time limit so that one slow step leaves the others their time.
# Records are appended to benchmarks/results/*.jsonl; the log goes to $OUT when set.
# Warp first (the default physics on a GPU), then the JAX backend's reference points.
set -uo pipefail
log=${OUT:-/tmp}/gpu_suite.log
step() { local limit=$1; shift; echo "+ $*" | tee -a "$log"; timeout "$limit" "$@" 2>&1 | tee -a "$log"; }
# physics alone, our env step against the bare physics, per backend and batch (the table)
step 240 python3 benchmarks/physics_throughput.py env=hopper physics=warp batches=125,1024,1250,16384 steps=200
step 150 python3 benchmarks/physics_throughput.py env=walker2d physics=warp batches=1024,8192 steps=200
step 240 python3 benchmarks/physics_throughput.py env=ant physics=warp batches=125,1060,16384 steps=100
step 240 python3 benchmarks/physics_throughput.py env=hopper physics=jax batches=1024 steps=100
# scoring rounds (N = 10, all episodes at once), training, Brax at matched settings
step 120 python3 benchmarks/scoring_round.py env=ant physics=warp n_episodes=10 slots=0 ceiling=false
step 120 python3 benchmarks/scoring_round.py env=hopper physics=warp n_episodes=10 slots=0
step 120 python3 benchmarks/train_throughput.py env=hopper physics=warp num_envs=128 iterations=30 roofline=true
step 120 python3 benchmarks/train_throughput.py env=hopper physics=warp num_envs=128 iterations=20 seeds=10
step 190 python3 benchmarks/brax_sac.py env=hopper physics=warp num_envs=128 steps_per_epoch=20 num_eval_envs=8
# one experiment of 10 pairs (5 seeds x 2 modes): per-iteration training and scoring seconds in metrics.jsonl
step 400 python3 -m admissable_jax.experiment env=hopper seeds=5 physics=warp total_steps=15000 progress=false out=runs/bench-pairs
tail -n 1 runs/bench-pairs/adversarial-s0/metrics.jsonl | tee -a "$log"
