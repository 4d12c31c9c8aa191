#!/usr/bin/env bash
# The GPU campaign, one step at a time, as a chain of device calls of at most 9 minutes each:
#
#   bash benchmarks/gpu_campaign.sh STEP          STEP = speed | hopper | walker2d | ant
#
#   speed     the speed table: our env step against the bare Warp physics (125, 1,250 and
#             10,000 worlds; graph modes), scoring rounds (untrained and full-length), training
#             (1 and 15 runs), Brax SAC, and each campaign run's own parts (campaign.py measure)
#   hopper    experiment env=hopper seeds=5 modes=adversarial,uniform,none total_steps=1000000
#             (the 10 adversarial/uniform pairs if the 15 cannot finish in the time left)
#   walker2d  the same on Walker2d
#   ant       the paper's protocol on Ant for as many env steps as the time left allows (>= 200k)
#
# Exit status: 0 the step is complete; 75 call again (the same command) to go on; 3 refused (a
# run that cannot finish in CAMPAIGN_DEADLINE seconds is never started); 4 packages missing;
# 1 a stage failed in smoke mode. Every call ends by packing what exists so far (run jsonl
# files, configs, logs, benchmark records) into $OUT/campaign-STEP.tar.gz (at most 16 MiB).
#
# On a lent GPU (device tool), from the repository root, after `bash ../shared/device/pack.sh`:
#   run(command="bash .dev/a/stage.sh", carry=[".dev/a"])
#   run(command="bash .dev/b/finish.sh && CAMPAIGN_DEADLINE=<device s left> bash benchmarks/gpu_campaign.sh speed", carry=[".dev/b"])
#   run(command="CAMPAIGN_DEADLINE=<device s left> bash benchmarks/gpu_campaign.sh speed")  # while it exits 75
# Run directories live in runs/campaign/ (ignored; kept while the machine stays warm).
# Step 5 runs here, on the CPU, from the tarballs that came back: unpack each into
# benchmarks/results/ and run `python benchmarks/figure1.py hopper=DIR walker2d=DIR ant=DIR`.
#
# Settings (environment):
#   CAMPAIGN_DEADLINE       device seconds left for this step (needed to start a run; `status` says)
#   CAMPAIGN_CALL_SECONDS   seconds one call may work (default 540: 9 minutes)
#   CAMPAIGN_SMOKE=1        every step end to end on the CPU at a tiny size (warp physics, 80 env
#                           steps, 2-3 pairs), records kept apart; tests run this
#   CAMPAIGN_DIR            where runs, records and the step's state go (default runs/campaign,
#                           runs/campaign-smoke in smoke mode)
#   CAMPAIGN_ONLY           a regular expression: the speed step runs only the stages it matches
#                           (e.g. 'measure-hopper' or 'brax'), to redo one or to test a few
#   CAMPAIGN_RUN_SECONDS    cap on one call's training seconds (tests set it tiny to make a run pause
#                           after one scoring and go on in the next call)
#   PYTHON                  the interpreter (default python3)
set -uo pipefail
step=${1:-}
case "$step" in
  speed|hopper|walker2d|ant) ;;
  *) echo "usage: bash benchmarks/gpu_campaign.sh speed|hopper|walker2d|ant (see the header)" >&2; exit 2 ;;
esac
repo=$(cd "$(dirname "$0")/.." && pwd)
cd "$repo"
smoke=${CAMPAIGN_SMOKE:-0}
call_seconds=${CAMPAIGN_CALL_SECONDS:-540}
py=${PYTHON:-python3}
if [ "$smoke" = 1 ]; then dir=${CAMPAIGN_DIR:-runs/campaign-smoke}; else dir=${CAMPAIGN_DIR:-runs/campaign}; fi
out=${OUT:-$dir/out}
mkdir -p "$dir/state" "$dir/results" "$out"
dir=$(cd "$dir" && pwd) out=$(cd "$out" && pwd)
state=$dir/state
log=$dir/$step.log
export BENCHMARK_RESULTS_DIR=$dir/results PYTHONUNBUFFERED=1 PYTHONPATH=$repo:$repo/benchmarks${PYTHONPATH:+:$PYTHONPATH}

left() { echo $(( call_seconds - SECONDS )); }

pack() {  # what exists so far, for the trip back: jsonl, yaml, logs, records
  local tarball=$out/campaign-$step.tar.gz
  (cd "$dir" && find . \( -name '*.jsonl' -o -name '*.yaml' -o -name '*.log' -o -path './state/*' \) \
      -not -path './out/*' -print0 | tar --null -czf "$tarball" -T -)
  local bytes; bytes=$(stat -c %s "$tarball")
  echo "packed $(tar -tzf "$tarball" | wc -l) files, $bytes bytes, into $tarball"
  [ "$bytes" -le 16777216 ] || echo "warning: $tarball is over 16 MiB and will not come back" >&2
}

again() { echo "call again: $1; run the same command to go on" | tee -a "$log"; pack; exit 75; }

stage() {  # stage NAME LIMIT COMMAND...: run once per campaign, within LIMIT seconds
  local name=$1 limit=$2; shift 2
  [ -e "$state/$name.done" ] && return 0
  [[ -z "${CAMPAIGN_ONLY:-}" || "$name" =~ $CAMPAIGN_ONLY ]] || return 0
  [ "$(left)" -ge "$limit" ] || again "stage $name needs up to ${limit} s, this call has $(left) s left"
  echo "+ $*" | tee -a "$log"
  timeout "$limit" "$@" 2>&1 | tee -a "$log"
  local status=${PIPESTATUS[0]}
  echo "$status" > "$state/$name.done"
  if [ "$status" -ne 0 ]; then
    echo "stage $name exited $status" | tee -a "$log"
    if [ "$smoke" = 1 ]; then pack; exit 1; fi  # smoke mode exists to find such failures
  fi
}

install() {  # the packages ../shared/device/pack.sh packs, into /tmp/site (device machines only)
  export PYTHONPATH=/tmp/site:$PYTHONPATH
  local check="import mujoco, warp, brax, omegaconf, gymnasium"
  $py -c "$check" 2>/dev/null && return 0
  [ -f .dev/a/stage.sh ] && bash .dev/a/stage.sh
  [ -f .dev/b/finish.sh ] && bash .dev/b/finish.sh
  $py -c "$check" 2>/dev/null && return 0
  echo "packages missing: run 'bash ../shared/device/pack.sh' here, then the two calls its header names" \
       "(.dev/a/stage.sh carrying .dev/a, then .dev/b/finish.sh && this script, carrying .dev/b)" >&2
  exit 4
}

# Sizes: the paper's on a GPU; tiny on the CPU in smoke mode. Both on MuJoCo Warp.
if [ "$smoke" = 1 ]; then
  full_steps=80  # the sizes of tests/test_hopper_pipelines.py, whose straight run the smoke chain must repeat
  sizes=(physics=warp seeds=1 score_every=40 num_envs=4 learning_starts=48 batch_size=32 hidden_size=32
         buffer_size=1000 score_episodes=2 score_envs=8 episode_length=10 checkpoint_every=1)
  min_steps=40; worlds=4,8; graph_modes=default; physics_steps=5; scoring=(n_episodes=1 max_steps=10)
  train_bench=(num_envs=4 iterations=4 batch_size=32 buffer_size=1000); brax=(num_envs=4 steps_per_epoch=4 batch_size=32 num_eval_envs=2 episode_length=10)
  deadline=${CAMPAIGN_DEADLINE:-3600}
else
  install
  export JAX_COMPILATION_CACHE_DIR=$repo/runs/jax_cache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=1
  full_steps=1000000
  sizes=(physics=warp seeds=5 score_every=5000)
  min_steps=200000; worlds=125,1250,10000; graph_modes=default,WARP,WARP_STAGED; physics_steps=100
  scoring=(n_episodes=10); train_bench=(num_envs=125 iterations=40); brax=(num_envs=125 steps_per_epoch=40)
  deadline=${CAMPAIGN_DEADLINE:-}
fi
if [ "$smoke" != 1 ]; then  # the versions and the device, for the log that comes back
  $py -c "import jax, mujoco, warp; print('campaign step $step: jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__, 'warp', warp.__version__)" \
    2>&1 | grep -v '^Warp' | tee -a "$log"
fi

ALL=adversarial,uniform,none
PAIRED=adversarial,uniform

train() {  # train ENV MODES [total_steps=N]: one experiment, resumed across calls until done
  local env=$1 modes=$2; shift 2
  local rundir=$dir/$env resume=false
  [ -n "$(ls -A "$rundir/checkpoints" 2>/dev/null)" ] && resume=true
  local budget=$(( $(left) - 30 ))  # 30 s for the pack at the end
  [ "$budget" -ge 60 ] || again "$(left) s left in this call"
  budget=${CAMPAIGN_RUN_SECONDS:-$budget}
  echo "+ experiment env=$env modes=$modes ${sizes[*]} $* resume=$resume time_limit=$budget" | tee -a "$log"
  $py -m admissable_jax.experiment env="$env" modes="$modes" "${sizes[@]}" "$@" out="$rundir" resume=$resume \
      time_limit="$budget" progress=false 2>&1 | tee "$dir/last-call.log" | tee -a "$log"
  local status=${PIPESTATUS[0]}
  [ "$status" -eq 0 ] || { echo "experiment exited $status" | tee -a "$log"; pack; exit "$status"; }
  if grep -q '^paused' "$dir/last-call.log"; then again "$env is not finished"; fi
  echo "$env finished" | tee -a "$log"
}

admitted() {  # admitted ENV MODES [plan keys]: is a fresh run of this shape projected to finish in time?
  local env=$1 modes=$2; shift 2
  [ -n "$deadline" ] || { echo "set CAMPAIGN_DEADLINE to the device seconds left (the device tool's status)" >&2; exit 2; }
  $py benchmarks/campaign.py plan env="$env" modes="$modes" "${sizes[@]}" deadline="$deadline" \
      call_seconds="$call_seconds" "$@" 2>&1 | grep -v '^Warp' | tee -a "$log" | tee "$dir/plan.out"
  return "${PIPESTATUS[0]}"
}

refused() { echo "refused: $1" | tee -a "$log"; pack; exit 3; }

case "$step" in
  speed)
    for env in hopper walker2d; do
      for modes in $ALL $PAIRED; do
        stage "measure-$env-$modes" 300 $py benchmarks/campaign.py measure env=$env modes=$modes "${sizes[@]}"
      done
    done
    stage measure-ant 300 $py benchmarks/campaign.py measure env=ant modes=$PAIRED "${sizes[@]}"
    for env in hopper ant walker2d; do
      modes=$graph_modes; [ "$env" = walker2d ] && modes=default
      stage "physics-$env" 300 $py benchmarks/physics_throughput.py env=$env physics=warp batches=$worlds \
          steps=$physics_steps graph_modes=$modes
    done
    stage physics-hopper-jax 240 $py benchmarks/physics_throughput.py env=hopper physics=jax batches=${worlds%%,*} steps=$physics_steps
    for env in hopper ant; do
      stage "scoring-$env" 200 $py benchmarks/scoring_round.py env=$env physics=warp slots=0 ceiling=false "${scoring[@]}"
      stage "scoring-$env-full" 200 $py benchmarks/scoring_round.py env=$env physics=warp slots=0 ceiling=false terminate=false "${scoring[@]}"
    done
    stage train-hopper-1 200 $py benchmarks/train_throughput.py env=hopper physics=warp "${train_bench[@]}"
    stage train-hopper-15 240 $py benchmarks/train_throughput.py env=hopper physics=warp seeds=15 "${train_bench[@]}"
    stage brax-hopper 300 $py benchmarks/brax_sac.py env=hopper physics=warp "${brax[@]}"
    ;;
  hopper|walker2d)
    chosen=$state/$step.modes
    if [ ! -e "$chosen" ]; then
      admitted "$step" $ALL total_steps=$full_steps; status=$?
      if [ $status -eq 0 ]; then echo $ALL > "$chosen"
      elif [ $status -eq 3 ]; then
        admitted "$step" $PAIRED total_steps=$full_steps; status=$?
        [ $status -eq 3 ] && refused "$step at $full_steps env steps cannot finish in $deadline s; give the time to the ant step"
        [ $status -eq 0 ] || exit $status
        echo $PAIRED > "$chosen"
        echo "all modes' pairs cannot finish in the time left; running the adversarial/uniform pairs" | tee -a "$log"
      else exit $status; fi
    fi
    train "$step" "$(cat "$chosen")" total_steps=$full_steps
    ;;
  ant)
    chosen=$state/ant.total_steps
    if [ ! -e "$chosen" ]; then
      admitted ant $PAIRED total_steps=0 min_steps=$min_steps max_steps=$full_steps; status=$?
      [ $status -eq 3 ] && refused "ant: fewer than $min_steps env steps fit in $deadline s"
      [ $status -eq 0 ] || exit $status
      tail -n 1 "$dir/plan.out" > "$chosen"
    fi
    train ant $PAIRED "$(cat "$chosen")"
    ;;
esac
echo "step $step complete" | tee -a "$log"
pack
