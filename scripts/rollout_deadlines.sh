#!/usr/bin/env bash
# Deadline misses of LeRobot's real-time rollout loop (stock `lerobot-rollout`: sync inference, base
# strategy), per DCDP execution mode, on the simulated PushT robot (real-time clock, constant drift).
# A tick "misses its deadline" when observation + policy + action took longer than 1/FPS: LeRobot's loop
# then logs "Record loop is running slower (X Hz) than the target FPS" (lerobot/rollout/strategies/base.py)
# and skips its sleep; we count those lines. The robot's own summary line gives the ticks (actions),
# `held_steps` (simulated 0.1 s steps the world ran under a stale target because the next action came late)
# and `superseded_actions` (actions overwritten by the next one before the world stepped: sent right after
# a late tick, never executed): the cost of the misses as the robot sees it (LeRobot does not catch up
# after a late tick). The robot runs the benchmark's 300-step episodes (ending on success, from seed 100000 on:
# --robot.episode_steps), so the mean score of the episodes finished in DURATION is reported too.
# Usage: scripts/rollout_deadlines.sh [corrector dir]    (default models/pusht-dcdp-state)
#   env: FPS=10 DURATION=30 MODES="open_loop dcdp object_anchored temporal_ensemble closed_loop"
#        PLANNING=sync|async (--policy.planning; async applies to open_loop, dcdp, object_anchored)
#        TICKS_PER_STEP=1 (--policy.ticks_per_step: FPS/10 holds each planned action for that many ticks)
#        PLANNER_CPUS= (async only: --policy.planner_cpus, e.g. "[1]": the base's worker on CPU 1, the loop
#        on the others)
#        PLANNER_PRIORITY=normal (async only: --policy.planner_priority; idle: the worker under SCHED_IDLE)
#        PERTURBATION=constant MAGNITUDE=2.0 OUT=runs/rollout_deadlines
#        LEROBOT_ROLLOUT=.venv/bin/lerobot-rollout (the CLI to run)
# Writes $OUT/<mode>.log and $OUT/summary.md (also printed).
set -euo pipefail
policy=${1:-models/pusht-dcdp-state}
FPS=${FPS:-10}; DURATION=${DURATION:-30}; OUT=${OUT:-runs/rollout_deadlines}
MODES=${MODES:-open_loop dcdp object_anchored temporal_ensemble closed_loop}
LEROBOT_ROLLOUT=${LEROBOT_ROLLOUT:-.venv/bin/lerobot-rollout}
PLANNING=${PLANNING:-sync}; TICKS_PER_STEP=${TICKS_PER_STEP:-1}; PLANNER_CPUS=${PLANNER_CPUS:-}
PLANNER_PRIORITY=${PLANNER_PRIORITY:-normal}
pin=(); [ -n "$PLANNER_CPUS" ] && pin=(--policy.planner_cpus="$PLANNER_CPUS")
[ "$PLANNER_PRIORITY" != normal ] && pin+=(--policy.planner_priority="$PLANNER_PRIORITY")
mkdir -p "$OUT"
{
  echo "policy \`$policy\`, planning=${PLANNING}${PLANNER_CPUS:+, planner_cpus=$PLANNER_CPUS}, planner_priority=${PLANNER_PRIORITY}, ticks_per_step=${TICKS_PER_STEP}, ${FPS} Hz, ${DURATION} s per mode, ${PERTURBATION:-constant} drift ${MAGNITUDE:-2.0} px/step,"
  echo "$(nproc) CPUs, OMP_NUM_THREADS=1, load average before: $(cut -d' ' -f1-3 /proc/loadavg), $(date -u +%FT%TZ)"
  echo
  echo "| mode | ticks | missed deadlines (LeRobot warnings) | missed % | slowest tick ms | held sim steps | superseded actions | max coverage | episodes finished | mean score |"
  echo "|---|---|---|---|---|---|---|---|---|---|"
} > "$OUT/summary.md"
for mode in $MODES; do
  log=$OUT/$mode.log
  OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1 "$LEROBOT_ROLLOUT" --robot.type=pusht_sim \
    --robot.perturbation="${PERTURBATION:-constant}" --robot.magnitude="${MAGNITUDE:-2.0}" \
    --robot.seed=100000 --robot.episode_steps=300 \
    --policy.path="$policy" --policy.execution="$mode" --policy.planning="$PLANNING" \
    --policy.ticks_per_step="$TICKS_PER_STEP" "${pin[@]}" --fps="$FPS" --duration="$DURATION" \
    --return_to_initial_position=false --play_sounds=false > "$log" 2>&1 \
    || { echo "rollout failed for $mode, see $log" >&2; exit 1; }
  summary=$(grep -o "PushTSim disconnected: .*" "$log") \
    || { echo "no 'PushTSim disconnected:' summary line in $log (did the robot disconnect?)" >&2; exit 1; }
  field() { sed -E "s/.*[ :]$1=([^ ]+).*/\1/" <<< "$summary"; }
  misses=$(grep -c "Record loop is running slower" "$log" || true)
  # no warning at all is a valid outcome (grep exits 1 on no match; pipefail would end the script)
  slowest=$(grep -o "running slower ([0-9.]* Hz)" "$log" | grep -o "[0-9.]*" | sort -g | head -1 || true)
  slowest_ms=$([ -n "$slowest" ] && awk -v hz="$slowest" 'BEGIN{printf "%.0f", 1000/hz}' || echo "-")
  ticks=$(field actions)
  pct=$(awk -v m="$misses" -v t="$ticks" 'BEGIN{printf "%.1f", 100*m/t}')
  episodes=$(grep -q " episodes=" <<< "$summary" && field episodes || echo 0)
  score=$([ "$episodes" -gt 0 ] && field mean_score || echo "-")
  echo "| $mode | $ticks | $misses | $pct | $slowest_ms | $(field held_steps) | $(field superseded_actions) | $(field max_coverage) | $episodes | $score |" \
    >> "$OUT/summary.md"
done
cat "$OUT/summary.md"
