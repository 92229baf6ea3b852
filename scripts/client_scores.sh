#!/usr/bin/env bash
# Score with real asynchronous delay: LeRobot's stock RobotClient (the base alone, open loop with its own chunk
# aggregation) against dcdp-robot-client (the corrector here, the same base planning on the server), both on
# LeRobot's stock policy server on loopback, driving pusht_sim in real time under block drift. The sim robot runs
# the benchmark's episodes by itself (--robot.episode_steps=300, ends on success, episode k from seed 100000 + k)
# and appends each finished episode to a JSON Lines file, so the stock client, which never reports a score, is
# scored the same way. One client at a time (2 cores); the unfinished last episode of a run is dropped.
# The sim's world steps at 10 Hz (the bases' rate): above 10 Hz both clients send one action per tick, so each
# chunk runs fps/10 times too fast (most actions are superseded); the third client, dcdp_hold, is
# dcdp-robot-client with --policy.ticks_per_step=fps/10 (each planned action held for that many ticks; only for
# fps a multiple of 10 above 10).
# Usage: scripts/client_scores.sh [corrector] [episodes] [fps...]
#   (defaults: models/pusht-dcdp-state-demos-late 8 10 30)
#   env: OUT=runs/client_scores PERTURBATION=constant MAGNITUDE=2.0 SEED=100000 CHUNK=16 (--actions_per_chunk)
#        CLIENTS="stock dcdp dcdp_hold" (which to run; files of the others in $OUT are kept and tabulated)
# Writes $OUT/<client>_<fps>.jsonl, $OUT/<client>_<fps>.log and $OUT/summary.md (also printed).
set -euo pipefail
corrector=${1:-models/pusht-dcdp-state-demos-late}; episodes=${2:-8}; shift $(( $# > 2 ? 2 : $# ))
rates=("$@"); [ $# -eq 0 ] && rates=(10 30)
OUT=${OUT:-runs/client_scores}; PERTURBATION=${PERTURBATION:-constant}; MAGNITUDE=${MAGNITUDE:-2.0}
SEED=${SEED:-100000}; CHUNK=${CHUNK:-16}; CLIENTS=${CLIENTS:-stock dcdp dcdp_hold}
ncpu=$(nproc); export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
mkdir -p "$OUT"; out=$(cd "$OUT" && pwd)
source scripts/stock_server.sh; start_stock_server "$corrector" "$out"
# 300 simulated steps of 0.1 s per episode at most, plus a margin for start-up (the server loads the base)
seconds=$(( episodes * 30 + 20 ))
robot=(--robot.type=pusht_sim --robot.perturbation="$PERTURBATION" --robot.magnitude="$MAGNITUDE"
       --robot.seed="$SEED" --robot.episode_steps=300 --robot.calibration_dir="$work/calib")
runs() { [[ " $CLIENTS " == *" $1 "* ]]; }
for fps in "${rates[@]}"; do
  if runs stock; then
    rm -f "$out/stock_$fps.jsonl"
    echo "fps=$fps: stock RobotClient ($base_type base alone), ${seconds} s" >&2
    # the stock client runs until interrupted; SIGINT makes it stop the robot (and the kill after 20 s more)
    timeout -s INT -k 20 "$seconds" "$py" -m lerobot.async_inference.robot_client \
      --server_address="127.0.0.1:$port" "${robot[@]}" --robot.episodes_path="$out/stock_$fps.jsonl" \
      --policy_type="$base_type" --pretrained_name_or_path="$work/served" --actions_per_chunk="$CHUNK" \
      --fps="$fps" >"$out/stock_$fps.log" 2>&1 || true
    [ -s "$out/stock_$fps.jsonl" ] || echo "warning: the stock client finished no episode, see $out/stock_$fps.log" >&2
  fi
  for client in dcdp dcdp_hold; do
    runs $client || continue
    hold=()
    if [ $client = dcdp_hold ]; then
      (( fps > 10 && fps % 10 == 0 )) || continue
      hold=(--policy.ticks_per_step=$(( fps / 10 )))
    fi
    rm -f "$out/${client}_$fps.jsonl"
    echo "fps=$fps: dcdp-robot-client ($corrector ${hold[*]}), ${seconds} s" >&2
    .venv/bin/dcdp-robot-client --server_address="127.0.0.1:$port" "${robot[@]}" \
      --robot.episodes_path="$out/${client}_$fps.jsonl" --policy.path="$corrector" "${hold[@]}" \
      --base_path="$work/served" --fps="$fps" --duration="$seconds" --actions_per_chunk="$CHUNK" \
      >"$out/${client}_$fps.log" 2>&1
  done
done
{
  echo "corrector \`$corrector\`, base \`$base\` ($base_type) on the stock policy server (loopback), pusht_sim in"
  echo "real time, $PERTURBATION drift $MAGNITUDE px/step, 300-step episodes from seed $SEED, --actions_per_chunk=$CHUNK,"
  echo "$ncpu CPUs, OMP_NUM_THREADS=1, $(date -u +%FT%TZ); command: CLIENTS=\"$CLIENTS\" scripts/client_scores.sh $corrector $episodes ${rates[*]}"
  echo
  .venv/bin/python scripts/client_scores.py "$out" "${rates[@]}"
} > "$out/summary.md"
cat "$out/summary.md"
