#!/usr/bin/env bash
# Set up, lint, check the import layers, type-check, build the documentation (warnings fail
# it) and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check .
.venv/bin/lint-imports --no-cache --no-logo  # the layers of pyproject.toml's [tool.importlinter]
.venv/bin/mypy  # the package, as [tool.mypy] in pyproject.toml says
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict --quiet  # into site/ (gitignored)
# The tests: the unmarked ones (lockstep cells, deterministic whatever the load) two at a time,
# then those marked serial (real-time cells) alone on the machine; an exit status of 5 (the
# arguments selected none of one part) is no failure.
.venv/bin/python -m pytest -q -n 2 --dist loadfile -m "not serial" "$@" || [ $? -eq 5 ]
.venv/bin/python -m pytest -q -m serial "$@" || [ $? -eq 5 ]
