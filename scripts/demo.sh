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
echo; echo "== kalictl enable: amplifiers on, brakes off; every joint holds where it is"
$kalictl enable
$kalictl servo list
echo; echo "== kalictl calibrate: every joint onto its nearest index pulse; exact angles from now on"
$kalictl calibrate
echo; echo "== kalictl move: a smooth joint move of the left arm, and back"
$kalictl move left --joints 20,30,-160,10,30,45 --speed 0.5
$kalictl move left --joints 0,45,-180,0,45,0 --speed 0.5
echo; echo "== kalictl run: a robot program, both arms pick up the bar, carry it and put it back"
$kalictl run scripts/example_carry.py
$kalictl top --once
echo; echo "== kalictl servo: read the PID of left joint 2, raise kp, switch joint 6 to the PD"
$kalictl servo get left 2
$kalictl servo set left 2 kp=14000
$kalictl servo select left 6 pd
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
$kalictl enable
sleep 1
$kalictl status | sed -n 1,2p
echo
