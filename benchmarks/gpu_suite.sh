#!/usr/bin/env bash
# The GPU benchmark suite, as run on a lent H100 (device tool) from the repository root:
#   . benchmarks/device_env.sh && bash benchmarks/gpu_suite.sh
# Each step has its own time limit so that one slow step leaves the others their time.
# Records are appended to benchmarks/results/*.jsonl; the log goes to $OUT when set.
set -uo pipefail
log=${OUT:-/tmp}/gpu_suite.log
step() { local limit=$1; shift; echo "+ $*" | tee -a "$log"; timeout "$limit" "$@" 2>&1 | grep -v -i warp | tee -a "$log"; }
step 130 python3 benchmarks/train_throughput.py env=hopper num_envs=128 iterations=30 roofline=true
step 190 python3 benchmarks/brax_sac.py env=hopper num_envs=128 steps_per_epoch=20 num_eval_envs=8
step 200 python3 benchmarks/scoring_round.py env=ant n_episodes=10 slots=0 ceiling=false
step 200 python3 benchmarks/scoring_round.py env=ant n_episodes=10 slots=256 ceiling=false
step 150 python3 benchmarks/scoring_round.py env=hopper n_episodes=10 slots=0
step 80 python3 benchmarks/train_throughput.py env=hopper num_envs=128 iterations=20 seeds=5
