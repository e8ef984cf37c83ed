#!/usr/bin/env bash
# Set up everything Kali needs on a fresh Debian machine with Python 3.11, one line per step;
# what apt, pip and the compiler print goes to setup.log (its tail is shown if a step fails).
# Safe to run again: it only installs what is missing.
#
# Debian packages, each only if missing:
#   libatomic1  the arena's lock-free words (ctypes into libatomic.so.1)
#   gcc         the compiled servo-path kernels (kali_daemons/core/csrc/)
#   rt-tests    cyclictest: the machine's own timing floor beside every benchmark
#   chromium    the dashboard test opens the web viewer headless
#   openssl     the bridge's TLS test makes its certificates
# Then a virtual environment .venv with the kali_daemons package and its test and docs extras
# (MkDocs for docs/), and the kernels' library built into kali_daemons/core/__pycache__ (a process
# that finds none builds it at start, never inside a cycle).
set -euo pipefail
cd "$(dirname "$0")/.."
log=setup.log
: > "$log"

step() {  # step WHAT COMMAND...: one line, the command's output to the log
  local what=$1
  shift
  echo "setup: $what"
  if ! "$@" >> "$log" 2>&1; then
    echo "setup: FAILED: $what; the last lines of $log:" >&2
    tail -n 30 "$log" >&2
    exit 1
  fi
}

missing=()
ldconfig -p 2>/dev/null | grep -q 'libatomic\.so\.1' || missing+=(libatomic1)
command -v cc >/dev/null 2>&1 || missing+=(gcc)
command -v cyclictest >/dev/null 2>&1 || missing+=(rt-tests)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
command -v openssl >/dev/null 2>&1 || missing+=(openssl)
if [ ${#missing[@]} -gt 0 ]; then
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  step "Debian's package lists (apt-get update)" "${sudo_cmd[@]}" apt-get update -qq
  step "Debian packages: ${missing[*]} (what each is for: scripts/setup.sh)" \
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi

python=${PYTHON:-}
if [ -z "$python" ]; then
  for p in python3.11 python3; do
    if command -v "$p" >/dev/null 2>&1; then python=$p; break; fi
  done
fi
[ -x .venv/bin/python ] || step "a virtual environment in .venv ($python)" "$python" -m venv .venv
step "pip itself, up to date" .venv/bin/python -m pip install -q --disable-pip-version-check \
  --upgrade pip
step "the kali_daemons package, its test and docs extras into .venv (pip install -e '.[test,docs]')" \
  .venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test,docs]'
step "the compiled kernels (python -m kali_daemons.core.kernels)" .venv/bin/python -m kali_daemons.core.kernels
echo "setup: ready ($(.venv/bin/python --version), kalictl at .venv/bin/kalictl; source .venv/bin/activate to put it on PATH)"
