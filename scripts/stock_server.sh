# Sourced by scripts/client_ticks.sh and scripts/client_scores.sh (bash, set -euo pipefail):
# start_stock_server <corrector dir> <log dir>: serves the corrector's base (a dcdp-serve-base copy) on LeRobot's
# stock policy server on a free loopback port, and returns once it listens. Sets: work (temp dir, removed on
# exit with the server), base, base_type, port, py, server (pid). On failure the server log is copied to
# <log dir>/server.log.
start_stock_server() {
  local corrector=$1 logdir=$2 found
  server=; work=$(mktemp -d); trap 'kill ${server:-} 2>/dev/null || true; rm -rf "$work"' EXIT
  mapfile -t found < <(.venv/bin/python -c "
import json, os, sys; c = json.load(open(os.path.join(sys.argv[1], 'config.json')))
b = os.path.normpath(os.path.join(sys.argv[1], c['base_policy_path']))
print(b); print(json.load(open(os.path.join(b, 'config.json')))['type'])" "$corrector")
  [ ${#found[@]} -eq 2 ] || { echo "cannot read the base of $corrector (config.json)" >&2; exit 1; }
  base=${found[0]}; base_type=${found[1]}
  .venv/bin/dcdp-serve-base --base "$base" --out "$work/served" >/dev/null
  port=$(.venv/bin/python -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
  py=$(pwd)/.venv/bin/python
  (cd "$work" && exec "$py" -m lerobot.async_inference.policy_server --host=127.0.0.1 --port="$port" \
    --inference_latency=0 >"$work/server.log" 2>&1) &
  server=$!
  # LeRobot's stock client gives up after ~1.5 s of retries: return only once the server listens
  for _ in $(seq 120); do (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null && return 0; sleep 0.5; done
  mkdir -p "$logdir"; cp "$work/server.log" "$logdir/server.log"
  echo "policy server did not start: $logdir/server.log" >&2; exit 1
}
