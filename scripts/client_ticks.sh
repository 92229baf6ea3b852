#!/usr/bin/env bash
# Tick times of dcdp-robot-client (the corrector in this process) against LeRobot's stock policy server (the
# base in another process) on loopback, driving pusht_sim in real time at constant 2.0 px/step: the base in its
# own process never holds this process's GIL (scripts/tick_times.py measures the in-process async worker).
# Usage: scripts/client_ticks.sh [corrector] [seconds] [fps...]   (defaults: models/pusht-dcdp-state-demos-late 30 10 30)
# Prints one summary per fps: ticks, chunks, late ticks, mean / p99 / max tick ms, mean round trip ms.
set -euo pipefail
corrector=${1:-models/pusht-dcdp-state-demos-late}; seconds=${2:-30}; shift $(( $# > 2 ? 2 : $# ))
rates=("$@"); [ $# -eq 0 ] && rates=(10 30)
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
source scripts/stock_server.sh; start_stock_server "$corrector" runs
for fps in "${rates[@]}"; do
  echo "fps=$fps"
  .venv/bin/dcdp-robot-client --server_address="127.0.0.1:$port" --robot.type=pusht_sim \
    --robot.perturbation=constant --robot.magnitude=2.0 --robot.seed=100000 \
    --robot.calibration_dir="$work/calib" --policy.path="$corrector" --base_path="$work/served" \
    --fps="$fps" --duration="$seconds" --actions_per_chunk=16 2>/dev/null | tail -1
done
