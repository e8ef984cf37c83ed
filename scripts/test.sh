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
.venv/bin/python -m pytest -q "$@"
