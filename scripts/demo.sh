#!/usr/bin/env bash
# Set up, start the Kali daemon set with config/default.yaml, show it working, stop it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
kalictl=.venv/bin/kalictl
$kalictl start -c config/default.yaml
trap '$kalictl stop' EXIT
sleep 2
echo; echo "== kalictl status (2 s after start)"; $kalictl status
echo; echo "== kalictl rate tg 20: the trajectory generator now runs every 20 ms"; $kalictl rate tg 20
sleep 2
echo; echo "== kalictl status (2 s later)"; $kalictl status
echo; echo "== kalictl mem: the shared-memory arena"; $kalictl mem
echo; echo "== kalictl estop: the operator presses the emergency stop; the system halts"
$kalictl estop
$kalictl status | sed -n 1,2p
echo; echo "== release the button, clear the fault, run the clock again"
$kalictl estop --release
$kalictl reset
$kalictl clock start
sleep 1
$kalictl status | sed -n 1,2p
echo
