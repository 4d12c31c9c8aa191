#!/usr/bin/env bash
# The GPU campaign, one step at a time:
#
#   bash benchmarks/gpu_campaign.sh STEP          STEP = speed | hopper | walker2d | ant
#
#   speed     the speed table: each campaign run's own parts (campaign.py measure: Hopper and
#             Walker2d with all 15 pairs, Ant with 10), our env step against the bare Warp
#             physics (125, 1,250 and 10,000 worlds; graph modes), scoring rounds (untrained and
#             full-length; and full-length checking for running episodes every 10 steps only),
#             training (1 and 15 runs), Brax SAC (and its update alone against
#             ours: CAMPAIGN_ONLY=brax-update runs just that); the Hopper and Ant runs' device
#             time op by op (campaign.py profile; CAMPAIGN_ONLY=^profile- runs just these);
#             last, steps 2-4 projected for a whole lease (campaign.py projections); first,
#             whether this machine repeats a run bit for bit (repeatability.py:
#             CAMPAIGN_ONLY='^repeatability-hopper$' runs just that, about two minutes)
#   hopper    experiment env=hopper seeds=5 modes=adversarial,uniform,none total_steps=1000000
#             (the 10 adversarial/uniform pairs if the 15 cannot finish in the time left; if
#             neither can, the 15 pairs for the longest run that fits, at least 200k env steps)
#   walker2d  the same on Walker2d
#   ant       the paper's protocol on Ant for as many env steps as the time left allows (>= 200k)
# A run the plan admits then goes on past its planned length, towards 1M, while the deadline
# allows: it stops after the last scoring interval that fits (experiment's time_limit), with
# every record it made, so a machine faster than the speed record's uses the time it saves.
#
# With CAMPAIGN_RECORDS=ARCHIVE the hopper, walker2d or ant step continues the runs an earlier
# lease brought back (a tar, e.g. benchmarks/results/fig1-hopper-340k-h200/runs.tar.xz, holding
# the step's env folder) instead of starting afresh: it unpacks them, plans the longest
# continuation that fits (their recorded intervals re-trained first, a chunk each, no scoring
# round) and runs `experiment ... resume=true fast_forward=true`, which checks every rebuilt
# state against the records bit for bit and stops at the first that differs (exit 1, "fast-forward
# diverged at env step N"), where this machine cannot continue them: about a minute in if it
# differs from the first interval on, a chunk (seconds) later for each interval it agrees.
#
# A step runs as one worker process in a process session of its own, which the device machine
# keeps running between calls while it stays warm: the GPU works on while no call is in flight,
# and a run is compiled once and never checkpointed for the next call. A call starts the
# step's worker (unless it runs already), prints the worker's log as it grows for at most
# CAMPAIGN_CALL_SECONDS, and packs what exists so far (run jsonl files, configs, logs,
# benchmark records) into $OUT/campaign-STEP.tar.gz (at most 16 MiB) for the trip back, and
# each run's best policy (best_policy.npz) into $OUT/campaign-STEP-policies.tar.gz (15 Hopper
# runs: about 13 MB, computed from the networks' sizes), which load_policy(run, "best"), audit
# best=true and video best=true read. Once its run has ended, a step exports each run's final
# policy (python -m admissable_jax.export: the actor of the last checkpoint as NumPy arrays,
# RUN/exported/policy-step<N>.npz; 15 Hopper runs: 4.4 MB, Ant's 10: 5.0 MB), packed into
# $OUT/campaign-STEP-final-policies.tar.gz: the checkpoints never leave the machine, and
# `audit policy=FILE.npz` scores these afresh in Gymnasium's own env.
#
# Exit status of a call: 0 the step is complete; 75 call again (the same command, at once: a
# machine idle for ~30 s is given back, its worker with it); 3 refused (a run that cannot
# finish in CAMPAIGN_DEADLINE seconds is never started); 4 packages missing; 2 another step's
# worker is running; else the worker's own failure (in smoke mode, 1: a stage failed). After a
# failure the next call starts a new worker: finished benchmark stages are skipped and a run
# resumes from its last checkpoint.
#
# On a lent GPU (device tool), from the repository root, after `python benchmarks/warp_kernels.py`
# (MuJoCo Warp's CUDA modules, built on the CPU: Warp loads them instead of compiling them in a
# run's first chunk; the packs report how many) and `python benchmarks/device_pack.py` (runs
# ../shared/device/pack.sh, then splits its packages so that each call below fits one transfer
# with the working tree; it refuses, before any device time is spent, where they cannot):
#   run(command="bash .dev/a/stage.sh", carry=[".dev/a"])
#   run(command="bash .dev/b/finish.sh && CAMPAIGN_DEADLINE=<device s left> bash benchmarks/gpu_campaign.sh speed", carry=[".dev/b", ".dev/kernels"])
#   run(command="bash benchmarks/gpu_campaign.sh speed")  # while it exits 75
# Run directories live in runs/campaign/ (ignored; kept while the machine stays warm).
# Step 5 runs here, on the CPU, from the tarballs that came back: unpack each into
# benchmarks/results/ and run `python benchmarks/figure1.py hopper=DIR walker2d=DIR ant=DIR`
# (and campaign-STEP-policies.tar.gz into the same folder, beside the records, to audit the runs'
# best policies in Gymnasium's own env: benchmarks/sim_to_sim.py; campaign-STEP-final-policies.tar.gz
# too, for their final ones: benchmarks/README.md, Step 5).
#
# Settings (environment; a value the script cannot read is refused at once: one line, exit 2):
#   CAMPAIGN_DEADLINE       device seconds this step may use, from its worker's start (needed to
#                           start a run; the run stops within it): the budget_left_s the first call
#                           reports less about 75 s (the second call's transfer, the last pack and return);
#                           read when a worker starts (one restarted after a failure: give it the time left)
#   CAMPAIGN_CALL_SECONDS   seconds one call follows the worker (default 540: 9 minutes)
#   CAMPAIGN_PACK_SECONDS   a following call also packs every this many seconds (default 60), so
#                           that a call cut short still brings back what its $OUT held
#   CAMPAIGN_SMOKE=1        every step end to end on the CPU at a tiny size (warp physics, 80 env
#                           steps, 2-3 pairs), records kept apart; tests run this
#   CAMPAIGN_DIR            where runs, records and the step's state go (default runs/campaign,
#                           runs/campaign-smoke in smoke mode)
#   CAMPAIGN_SPEED_DEVICE   plan runs from this device's speed records (campaign.py plan's
#                           speed_device), e.g. 'gpu:NVIDIA H100 80GB HBM3' on an H200 that has
#                           none of its own (the same chip with faster memory: an upper bound)
#   CAMPAIGN_MIN_STEPS      the shortest run a step starts (default 200000, the issue's floor for
#                           Ant; 40 in smoke mode): in a 15-minute lease no Ant run of 200k fits
#                           (about 105k do), so `CAMPAIGN_MIN_STEPS=50000 ... ant` runs the longest
#                           that does, for the partial curves and the measured cost per interval
#   CAMPAIGN_ONLY           a regular expression: the speed step runs only the stages it matches
#                           (e.g. 'measure-hopper' or 'brax'), to redo one or to test a few
#   CAMPAIGN_RESERVE        seconds of the deadline a run leaves unused (default 50): its start
#                           before experiment's clock does (imports, ~10 s), the checkpoint it
#                           saves where it stops (Ant's 10 runs: 16 s) and the export of its
#                           final policies after it (one process: 4.5 s for 3 smoke pairs on a
#                           2-core CPU). A run goes on past its planned length while the
#                           deadline allows (experiment's time_limit)
#   CAMPAIGN_RUN_SECONDS    the worker's run pauses (checkpoints and stops, as experiment's time_limit)
#                           after this many seconds and the call says to call again; the next
#                           worker resumes it (tests use it; 0 or unset: no limit)
#   CAMPAIGN_RECORDS        an archive of the step's runs to continue (above; relative to the
#                           repository root); read when the worker starts
#   CAMPAIGN_FIRST_SEED     the runs' first seed (default 0): CAMPAIGN_FIRST_SEED=5 trains seeds
#                           5-9, new seeds for a result that seeds 0-4 gave
#   CAMPAIGN_DETERMINISTIC  1 (default): runs on the mujoco-warp package in its deterministic mode
#                           (deterministic_physics=true, said whatever experiment's default),
#                           with XLA's deterministic GPU ops, which a later lease needs to continue
#                           them; 0: on MJX's own copy of MuJoCo Warp in the GPU's own order
#                           (ADMISSABLE_MJX_OWN_WARP=1, deterministic_physics=false, XLA's
#                           defaults), as every run before 2026-12-04: the
#                           fallback should the package fail on a GPU (the hopper, walker2d and ant
#                           steps; the speed step's benchmarks build their envs deterministic)
#   PYTHON                  the interpreter (default python3)
set -uo pipefail
step=${1:-}
case "$step" in
  speed|hopper|walker2d|ant) ;;
  *) echo "usage: bash benchmarks/gpu_campaign.sh speed|hopper|walker2d|ant (see the header)" >&2; exit 2 ;;
esac
role=${2:-call}  # call, or --worker: the step itself (started by a call, never by hand)
# The settings checked at once, one line and exit 2 for a bad one: read as they are, a typo
# would pass for the default (CAMPAIGN_DETERMINISTIC=false runs the deterministic mode) or
# fail minutes into the lease.
setting() {  # setting NAME REGEX WHAT: NAME, where set, must match REGEX
  local value=${!1:-}
  [[ -z "$value" || "$value" =~ $2 ]] || { echo "$1=$value: give $3 (see the header)" >&2; exit 2; }
}
for name in CAMPAIGN_SMOKE CAMPAIGN_DETERMINISTIC; do setting "$name" '^[01]$' "1 or 0"; done
for name in CAMPAIGN_CALL_SECONDS CAMPAIGN_PACK_SECONDS CAMPAIGN_MIN_STEPS CAMPAIGN_FIRST_SEED; do
  setting "$name" '^[0-9]+$' "a whole number >= 0"
done
for name in CAMPAIGN_DEADLINE CAMPAIGN_RESERVE CAMPAIGN_RUN_SECONDS; do
  setting "$name" '^[0-9]+([.][0-9]*)?$' "a number of seconds >= 0"
done
repo=$(cd "$(dirname "$0")/.." && pwd)
cd "$repo"
smoke=${CAMPAIGN_SMOKE:-0}
call_seconds=${CAMPAIGN_CALL_SECONDS:-540}
reserve=${CAMPAIGN_RESERVE:-50}
pack_seconds=${CAMPAIGN_PACK_SECONDS:-60}
py=${PYTHON:-python3}
if [ "$smoke" = 1 ]; then dir=${CAMPAIGN_DIR:-runs/campaign-smoke}; else dir=${CAMPAIGN_DIR:-runs/campaign}; fi
mkdir -p "$dir/state" "$dir/results"
dir=$(cd "$dir" && pwd)
state=$dir/state
log=$dir/$step.log
records=${CAMPAIGN_RECORDS:-}
if [ -n "$records" ]; then
  [ "$step" != speed ] || { echo "CAMPAIGN_RECORDS continues a run: it goes with hopper, walker2d or ant, not speed" >&2; exit 2; }
  [ -f "$records" ] || { echo "CAMPAIGN_RECORDS=$records: no such file (an archive of $step runs, e.g. benchmarks/results/fig1-$step-*/runs.tar.xz)" >&2; exit 2; }
  records=$(cd "$(dirname "$records")" && pwd)/$(basename "$records")
fi
export BENCHMARK_RESULTS_DIR=$dir/results PYTHONUNBUFFERED=1 PYTHONPATH=$repo:$repo/benchmarks${PYTHONPATH:+:$PYTHONPATH}

kernels=$dir/warp_cache  # a Warp kernel cache: MuJoCo Warp's CUDA modules, prebuilt on the CPU

install() {  # the packages ../shared/device/pack.sh packs, into /tmp/site (device machines only)
  export PYTHONPATH=/tmp/site:$PYTHONPATH
  # The CUDA modules benchmarks/warp_kernels.py built on the CPU, if this call carried them
  # (a call's carried folders do not stay for the next: the call that starts the worker
  # carries them), an archive per MuJoCo Warp setup: Warp loads them instead of compiling
  # them in the run's first chunk.
  local archive unpacked=true
  if [ ! -e "$kernels/.unpacked" ] && compgen -G ".dev/kernels/*.tar.xz" > /dev/null; then
    for archive in .dev/kernels/*.tar.xz; do
      tar -xmJf "$archive" -C "$dir" || unpacked=false  # -m: their times, this clock's
    done
    [ "$unpacked" = true ] && touch "$kernels/.unpacked"
  fi
  [ -e "$kernels/.unpacked" ] && export WARP_CACHE_PATH=$kernels
  local check="import mujoco, warp, mujoco_warp, brax, omegaconf, gymnasium"
  $py -c "$check" 2>/dev/null && return 0
  [ -f .dev/a/stage.sh ] && bash .dev/a/stage.sh
  [ -f .dev/b/finish.sh ] && bash .dev/b/finish.sh
  $py -c "$check" 2>/dev/null && return 0
  echo "packages missing: run 'python benchmarks/device_pack.py' here, then the two calls this script's header names" \
       "(.dev/a/stage.sh carrying .dev/a, then .dev/b/finish.sh && this script, carrying .dev/b and .dev/kernels)" >&2
  exit 4
}

# Sizes: the paper's on a GPU; tiny on the CPU in smoke mode. Both on MuJoCo Warp.
if [ "$smoke" = 1 ]; then
  full_steps=80  # the sizes of tests/test_hopper_pipelines.py, whose straight run the smoke chain must repeat
  sizes=(physics=warp seeds=1 score_every=40 num_envs=4 learning_starts=48 batch_size=32 hidden_size=32
         buffer_size=1000 score_episodes=2 score_envs=24 episode_length=10 checkpoint_every=1)
  min_steps=${CAMPAIGN_MIN_STEPS:-40}; worlds=4,8; graph_modes=default; physics_steps=10; scoring=(n_episodes=1 max_steps=10)
  train_bench=(num_envs=4 iterations=4 batch_size=32 buffer_size=1000); brax=(num_envs=4 steps_per_epoch=4 batch_size=32 num_eval_envs=2 episode_length=10)
  repeat=(total_steps=80 learning_starts=48); cost_worlds=4; check=(batches=4 steps=$physics_steps)
  repeat_keys="physics=warp score_every=40 num_envs=4 batch_size=32 hidden_size=32 buffer_size=1000 score_episodes=2 score_envs=24 episode_length=10"
  deadline=${CAMPAIGN_DEADLINE:-3600}; lease=3600
else
  export JAX_COMPILATION_CACHE_DIR=$repo/runs/jax_cache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=1
  full_steps=1000000
  # A checkpoint every 20 scorings (100k env steps): runs cannot leave the machine, so one only
  # serves a worker restarted on it after a failure; each save of the replay buffers costs seconds.
  sizes=(physics=warp seeds=5 score_every=5000 checkpoint_every=20)
  min_steps=${CAMPAIGN_MIN_STEPS:-200000}; worlds=125,1250,10000; graph_modes=default,WARP,WARP_STAGED; physics_steps=100
  scoring=(n_episodes=10); train_bench=(num_envs=125 iterations=40); brax=(num_envs=125 steps_per_epoch=40)
  repeat=(total_steps=20000 learning_starts=10000); repeat_keys="physics=warp score_every=5000"
  cost_worlds=1875  # the Hopper step's 15 pairs x 125 envs
  check=(batches=125 steps=20)  # one pair's envs: every kernel launched from Python, Warp's buffers read back
  deadline=${CAMPAIGN_DEADLINE:-}; lease=690
fi
# Runs that a GPU repeats bit for bit, so that a later lease can continue them (fast_forward):
# MuJoCo Warp in its deterministic mode (experiment's deterministic_physics, on by default),
# and XLA's deterministic GPU ops without timing-based kernel choices (autotuning), which
# may differ from machine to machine. CAMPAIGN_DETERMINISTIC=0: neither (header).
deterministic=${CAMPAIGN_DETERMINISTIC:-1}
if [ "$deterministic" = 0 ]; then
  export ADMISSABLE_MJX_OWN_WARP=1
  sizes+=(deterministic_physics=false)
  repeat_keys+=" deterministic_physics=false"
else  # said, not left to the default, which may change (benchmarks/README.md, Leases, in order, 5)
  sizes+=(deterministic_physics=true)
  repeat_keys+=" deterministic_physics=true"
  export XLA_FLAGS="--xla_gpu_deterministic_ops=true --xla_gpu_autotune_level=0${XLA_FLAGS:+ $XLA_FLAGS}"
fi
sizes+=(first_seed=${CAMPAIGN_FIRST_SEED:-0})  # seeds first_seed, first_seed + 1, ...
ALL=adversarial,uniform,none
PAIRED=adversarial,uniform

# ---- the worker: the step itself, its output appended to $log ----

stage() {  # stage NAME LIMIT COMMAND...: run once per campaign, for at most LIMIT seconds
  local name=$1 limit=$2; shift 2
  [ -e "$state/$name.done" ] && return 0
  [[ -z "${CAMPAIGN_ONLY:-}" || "$name" =~ $CAMPAIGN_ONLY ]] || return 0
  echo "+ $*"
  timeout "$limit" "$@" 2>&1
  local status=$?
  echo "$status" > "$state/$name.done"
  if [ "$status" -ne 0 ]; then
    echo "stage $name exited $status"
    [ "$smoke" = 1 ] && exit 1  # smoke mode exists to find such failures
  fi
}

train() {  # train ENV modes=M total_steps=N: the planned run of N env steps, on past N to max_steps
            # while the deadline allows (resumed if a worker left checkpoints; else, continuing
            # records, rebuilt from them)
  local env=$1 modes=$2 planned=${3#total_steps=}
  local rundir=$dir/$env resume=false forward=false
  if [ -n "$(ls -A "$rundir/checkpoints" 2>/dev/null)" ]; then resume=true
  elif [ -n "$records" ]; then resume=true; forward=true; fi
  # The plan's N is what the speed record promises; the machine may be faster (an H200 compiles
  # in a third of the H100's time). So the run's bound is the deadline itself, as experiment's
  # time_limit: the seconds this worker has left less CAMPAIGN_RESERVE; the run stops after the
  # last scoring interval that fits (at least one), its records complete. A shorter
  # CAMPAIGN_RUN_SECONDS pauses it for the next worker instead (tests: a worker that failed).
  local limit by_deadline=true
  limit=$(awk -v deadline="$deadline" -v spent="$SECONDS" -v reserve="$reserve" \
              'BEGIN { left = int(deadline - spent - reserve); print (left >= 1 ? left : 1) }')
  if awk -v test="${CAMPAIGN_RUN_SECONDS:-0}" -v limit="$limit" 'BEGIN { exit !(test > 0 && test < limit) }'; then
    limit=$CAMPAIGN_RUN_SECONDS by_deadline=false
  fi
  echo "+ experiment env=$env $modes total_steps=$full_steps ${sizes[*]} resume=$resume fast_forward=$forward" \
       "time_limit=$limit ($planned env steps planned, then on while the deadline allows)"
  $py -m admissable_jax.experiment env="$env" "$modes" total_steps=$full_steps "${sizes[@]}" out="$rundir" resume=$resume \
      fast_forward=$forward time_limit="$limit" progress=false 2>&1 | tee "$dir/last-run.log"
  local status=${PIPESTATUS[0]}
  if grep -q 'fast-forward diverged' "$dir/last-run.log"; then
    echo "the records cannot be continued on this machine: it does not compute their runs bit for bit (above)"
  fi
  [ "$status" -eq 0 ] || { echo "experiment exited $status"; exit "$status"; }
  local paused; paused=$(grep -o '^paused at [0-9]*' "$dir/last-run.log" | grep -o '[0-9]*$')
  if [ -z "$paused" ]; then echo "$env finished"
  elif [ "$by_deadline" = true ]; then echo "$env stopped at the deadline: $paused env steps ($planned planned)"
  else echo "$env is not finished: the next worker resumes it"; exit 75; fi
}

export_final() {  # export_final ENV: each run's policy where it stopped (its last checkpoint) as NumPy
                  # arrays, for the trip back (the checkpoints, replay buffers and all, never leave the
                  # machine): audit policy=FILE.npz scores it afresh in Gymnasium's own env. At most
                  # 120 s (3 smoke pairs: 4.5 s on a 2-core CPU), so that a hung export cannot eat the lease
  echo "+ python -m admissable_jax.export $dir/$1"
  timeout 120 $py -m admissable_jax.export "$dir/$1" 2>&1 | grep -v '^Warp'
  local status=${PIPESTATUS[0]}
  if [ "$status" -ne 0 ]; then
    echo "export exited $status: the runs' final policies will not come back (their records will)"
    [ "$smoke" = 1 ] && exit 1  # smoke mode exists to find such failures
  fi
}

refused() { echo "refused: $1"; exit 3; }

unpack_records() {  # unpack_records ENV: the ENV/ folder of $records as $dir/ENV, once
  local env=$1 scratch=$dir/records.unpacking
  [ -d "$dir/$env" ] && return 0
  rm -rf "$scratch" && mkdir -p "$scratch"
  $py -c 'import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2], filter="data")' "$records" "$scratch" \
    || { echo "cannot unpack $records"; exit 2; }  # Python's tarfile: gzip and xz whatever the machine has
  [ -d "$scratch/$env" ] || { echo "$records holds no $env/ folder"; exit 2; }
  mv "$scratch/$env" "$dir/$env" && rm -rf "$scratch"
  echo "continuing the $env runs of $records"
}

choose() {  # choose ENV MODES [plan keys]: campaign.py plan picks the run (its last line, kept in $chosen), or refuse
  local env=$1 modes=$2 status; shift 2
  [ -n "$deadline" ] || { echo "set CAMPAIGN_DEADLINE to the device seconds left (the device tool's status)"; exit 2; }
  local keys=(env="$env" modes="$modes" "${sizes[@]}" deadline="$deadline" min_steps=$min_steps max_steps=$full_steps
              ${CAMPAIGN_SPEED_DEVICE:+"speed_device=$CAMPAIGN_SPEED_DEVICE"} "$@")
  echo "+ campaign.py plan ${keys[*]}"
  $py benchmarks/campaign.py plan "${keys[@]}" 2>&1 | grep -v '^Warp' | tee "$dir/plan.out"
  status=${PIPESTATUS[0]}
  [ $status -eq 3 ] && refused "$env: fewer than $min_steps env steps fit in $deadline s"
  [ $status -eq 0 ] || exit $status
  tail -n 1 "$dir/plan.out" > "$chosen"
}

worker() {
  if [ "$smoke" != 1 ]; then  # the versions and the device, for the log that comes back
    $py -c "import jax, mujoco, os, warp; print('campaign step $step: jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__, 'warp', warp.__version__, 'WARP_CACHE_PATH', os.environ.get('WARP_CACHE_PATH'))" \
      2>&1 | grep -v '^Warp'
    $py -c "from admissable_jax.envs import physics, warp_package; import os; print('MuJoCo Warp:', warp_package.which(), '| XLA_FLAGS:', os.environ.get('XLA_FLAGS'))" \
      2>&1 | grep -v '^Warp'
  fi
  # Continuing records (CAMPAIGN_RECORDS; never with speed): the records' pairs, past them as
  # far as the time allows, planned from their folder; a fresh run may fall back to fewer pairs.
  local continuing=() fallback=(fallback_modes=$PAIRED)
  if [ -n "$records" ]; then
    unpack_records "$step"
    continuing=(records="$dir/$step") fallback=()
  fi
  case "$step" in
    speed)
      # Whether this machine repeats a run bit for bit (a short experiment, then its records alone
      # fast-forwarded in a fresh process): what continuing a run on the next lease needs.
      stage repeatability-hopper 600 $py benchmarks/repeatability.py env=hopper "${repeat[@]}" "extra=$repeat_keys" \
          out="$dir/repeatability"
      # ...and what that mode costs: the env step at the Hopper step's size with it and without
      # (the package in the GPU's own order), one process each (one setting per process); then
      # the mode without a CUDA graph (graph mode NONE), where Warp checks after each launch that
      # no thread outgrew the mode's record buffers (in a graph, an overflow goes unsaid): a
      # fault fails that stage with Warp's message.
      if [ "$deterministic" != 0 ]; then
        for mode in true false; do
          stage "determinism-cost-hopper-$mode" 200 $py benchmarks/physics_throughput.py env=hopper physics=warp \
              batches=$cost_worlds steps=$physics_steps deterministic=$mode
        done
        stage determinism-cost-hopper-true-graphless 200 $py benchmarks/physics_throughput.py env=hopper physics=warp \
            "${check[@]}" deterministic=true graph_modes=NONE
      fi
      stage measure-hopper 300 $py benchmarks/campaign.py measure env=hopper modes=$ALL "${sizes[@]}"
      stage measure-walker2d 300 $py benchmarks/campaign.py measure env=walker2d modes=$ALL "${sizes[@]}"
      stage measure-ant 300 $py benchmarks/campaign.py measure env=ant modes=$PAIRED "${sizes[@]}"
      # The same runs' device time, op by op, for one chunk and one full-length scoring round:
      # where a latency-bound GPU waits (CAMPAIGN_ONLY=^profile- runs just these, before a step).
      stage profile-hopper 300 $py benchmarks/campaign.py profile env=hopper modes=$ALL "${sizes[@]}"
      stage profile-ant 300 $py benchmarks/campaign.py profile env=ant modes=$PAIRED "${sizes[@]}"
      for env in hopper ant walker2d; do
        modes=$graph_modes; [ "$env" = walker2d ] && modes=default
        stage "physics-$env" 300 $py benchmarks/physics_throughput.py env=$env physics=warp batches=$worlds \
            steps=$physics_steps graph_modes=$modes
      done
      stage physics-hopper-jax 240 $py benchmarks/physics_throughput.py env=hopper physics=jax batches=${worlds%%,*} steps=$physics_steps
      for env in hopper ant; do
        stage "scoring-$env" 200 $py benchmarks/scoring_round.py env=$env physics=warp slots=0 ceiling=false "${scoring[@]}"
        stage "scoring-$env-full" 200 $py benchmarks/scoring_round.py env=$env physics=warp slots=0 ceiling=false terminate=false "${scoring[@]}"
        # The same round checking for running episodes every 10 steps only (score_missingness's
        # steps_per_check): each check of a data-dependent loop makes the host wait for the GPU.
        stage "scoring-$env-full-check10" 200 $py benchmarks/scoring_round.py env=$env physics=warp slots=0 ceiling=false \
            terminate=false steps_per_check=10 "${scoring[@]}"
      done
      stage train-hopper-1 200 $py benchmarks/train_throughput.py env=hopper physics=warp "${train_bench[@]}"
      stage train-hopper-15 240 $py benchmarks/train_throughput.py env=hopper physics=warp seeds=15 "${train_bench[@]}"
      stage brax-hopper 300 $py benchmarks/brax_sac.py env=hopper physics=warp "${brax[@]}"
      # Brax's SAC update against ours alone (no env): where the training gap to Brax lies.
      stage brax-update-hopper 200 $py benchmarks/brax_sac.py env=hopper update_only=true
      # Steps 2-4 projected for one whole lease: 15 minutes (900 s) less the start and staging
      # (about 150 s) and the last return (60 s), as results/campaign_projections_15min.txt.
      stage projections 120 $py benchmarks/campaign.py projections "${sizes[@]}" total_steps=$full_steps \
          deadline=$lease min_steps=$min_steps max_steps=$full_steps
      ;;
    hopper|walker2d)
      # The paper's 1M env steps: the 15 pairs if they fit, else the 10 (adversarial, uniform);
      # if neither fits (a Hopper run needs more than one lease on an H100: speed step), the 15
      # pairs for the longest run the time allows, as the ant step does. One plan decides.
      chosen=$state/$step.run
      [ -e "$chosen" ] || choose "$step" $ALL total_steps=$full_steps "${fallback[@]}" or_longest=true "${continuing[@]}"
      train "$step" $(cat "$chosen")
      export_final "$step"
      ;;
    ant)
      chosen=$state/ant.run
      [ -e "$chosen" ] || choose ant $PAIRED total_steps=0 "${continuing[@]}"
      train ant $(cat "$chosen")
      export_final ant
      ;;
  esac
  echo "step $step complete"
  touch "$state/$step.complete"
}

if [ "$role" = --worker ]; then worker; exit 0; fi
# An expansion error in the worker ends the `if` above without its exit: never go on as a call.
[ "$role" != --worker ] || { echo "the $step worker stopped at an error in this script (above)"; exit 1; }

# ---- a call: start the worker if none runs, follow its log, pack ----

out=${OUT:-$dir/out}
mkdir -p "$out"
out=$(cd "$out" && pwd)
pidfile=$state/$step.pid statusfile=$state/$step.status shownfile=$state/$step.shown

pack() {  # what exists so far, for the trip back: jsonl, yaml, the runs' feature names, logs, records
  kernel_report > "$dir/warp-kernels.log"
  pack_apart "campaign-$step" "files" "; $(cat "$dir/warp-kernels.log")" \( -name '*.jsonl' -o -name '*.yaml' \
      -o -name observation_names.json -o -name '*.log' -o -path './state/*' \)
  # The policies in files of their own, so that the records come back whatever their size: each
  # of this step's runs' best (best_policy.npz, about 1 MB: the networks without the replay
  # buffer) and, once the step is complete, its final one (admissable_jax.export's, the actor
  # alone: 0.3-0.5 MB); not an earlier step's on this machine, which came back with it.
  pack_apart "campaign-$step-policies" "best policies" "" -path "./$step/*" -name best_policy.npz
  pack_apart "campaign-$step-final-policies" "final policies" "" -path "./$step/*/exported/policy-step*.npz"
}

pack_apart() {  # pack_apart NAME WHAT NOTE FIND-TESTS...: the files the tests find (not in out/) into $out/NAME.tar.gz
  local tarball=$out/$1.tar.gz what=$2 note=$3 bytes; shift 3
  (cd "$dir" && find . "$@" -not -path './out/*' -print0 | tar --null -czf "$tarball" -T -)
  bytes=$(stat -c %s "$tarball")
  echo "packed $(tar -tzf "$tarball" | wc -l) $what, $bytes bytes, into $tarball$note"
  [ "$bytes" -le 16777216 ] || echo "warning: $tarball is over 16 MiB and will not come back" >&2
}

kernel_report() {  # how many Warp modules came prebuilt and how many this machine compiled
  [ -e "$kernels/.unpacked" ] || { echo "Warp kernel cache: none prebuilt (no .dev/kernels carried by the call that started the worker)"; return 0; }
  echo "Warp kernel cache: $(find "$kernels" -name '*.cubin' ! -newer "$kernels/.unpacked" | wc -l) modules prebuilt," \
       "$(find "$kernels" \( -name '*.cubin' -o -name '*.ptx' \) -newer "$kernels/.unpacked" | wc -l) compiled on this machine"
}

alive() {  # alive PIDFILE: does the worker it names run? Its pid alone may say so wrongly: an
           # ended worker nobody has reaped yet (a zombie has no command line), or its pid
           # given to another process or thread since (a busy machine cycles through 32,768
           # in minutes), even to a call of this script; so its command line must be a worker's
  local pid
  [ -s "$1" ] || return 1
  pid=$(cat "$1")
  kill -0 "$pid" 2>/dev/null || return 1
  [ ! -e "/proc/$pid" ] || { grep -qa gpu_campaign.sh "/proc/$pid/cmdline" && grep -qa -e --worker "/proc/$pid/cmdline"; } 2>/dev/null
}

show_log() {  # the worker's log lines no call has printed yet
  local shown=0 lines
  [ -e "$shownfile" ] && shown=$(cat "$shownfile")
  [ -e "$log" ] || return 0
  lines=$(wc -l < "$log")
  [ "$lines" -gt "$shown" ] && sed -n "$((shown + 1)),${lines}p" "$log"
  echo "$lines" > "$shownfile"
}

for other in "$state"/*.pid; do
  if [ "$other" != "$pidfile" ] && alive "$other"; then
    echo "the $(basename "$other" .pid) worker is running (pid $(cat "$other")): follow it to its end first" >&2
    exit 2
  fi
done
if [ -e "$state/$step.complete" ]; then
  show_log; echo "step $step complete"; pack; exit 0
fi
if alive "$pidfile"; then
  echo "following the $step worker (pid $(cat "$pidfile"))"
elif [ ! -e "$statusfile" ]; then
  [ "$smoke" = 1 ] || install
  rm -f "$pidfile"
  setsid bash -c 'echo $$ > "$1"; bash "$2" "$3" --worker; echo $? > "$4"' worker "$pidfile" \
      "$repo/benchmarks/gpu_campaign.sh" "$step" "$statusfile" >> "$log" 2>&1 < /dev/null &
  for _ in $(seq 100); do [ -s "$pidfile" ] && break; sleep 0.1; done
  [ -s "$pidfile" ] || { echo "the $step worker did not start (setsid?); see $log" >&2; exit 1; }
  echo "started the $step worker (pid $(cat "$pidfile")) in a process session of its own; its log: $log"
fi
packed_at=$SECONDS
while alive "$pidfile" && [ "$SECONDS" -lt "$call_seconds" ]; do
  show_log; sleep 2
  # Pack now and then too: what lies in $OUT comes back even from a call cut short.
  if [ $((SECONDS - packed_at)) -ge "$pack_seconds" ]; then pack; packed_at=$SECONDS; fi
done
show_log
if alive "$pidfile"; then
  echo "call again: the $step worker (pid $(cat "$pidfile")) runs on; run the same command at once to follow it"
  pack; exit 75
fi
if [ -e "$statusfile" ]; then status=$(cat "$statusfile")
else echo "the $step worker (pid $(cat "$pidfile")) was killed; the next call starts a new one" >&2; status=1; fi
rm -f "$statusfile" "$pidfile"
[ "$status" -eq 75 ] && echo "call again: run the same command to go on"
pack
exit "$status"
