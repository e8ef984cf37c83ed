#!/usr/bin/env bash
# Set up everything Kali needs on a fresh Debian machine with Python 3.11:
#   - Debian packages: libatomic1 (the arena's test-and-set), rt-tests (cyclictest, for the
#     timing benchmarks' floor), chromium (the dashboard test opens the web viewer headless),
#     openssl (the bridge's TLS test makes its certificates);
#   - a C compiler (gcc) for the servo path's kernels (kali_daemons/kernels.c);
#   - a virtual environment in .venv with the kali_daemons package and its test extras;
#   - the kernels' library, built into kali_daemons/__pycache__ (python -m kali_daemons.kernels;
#     a process that finds none builds it at start, never inside a cycle).
# Safe to run again: it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
ldconfig -p 2>/dev/null | grep -q 'libatomic\.so\.1' || missing+=(libatomic1)
command -v cyclictest >/dev/null 2>&1 || missing+=(rt-tests)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
command -v cc >/dev/null 2>&1 || missing+=(gcc)
command -v openssl >/dev/null 2>&1 || missing+=(openssl)
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi

python=${PYTHON:-}
if [ -z "$python" ]; then
  for p in python3.11 python3; do
    if command -v "$p" >/dev/null 2>&1; then python=$p; break; fi
  done
fi
[ -x .venv/bin/python ] || "$python" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test]'
.venv/bin/python -m kali_daemons.kernels
echo "setup: ready ($(.venv/bin/python --version), kalictl at .venv/bin/kalictl; source .venv/bin/activate to put it on PATH)"
