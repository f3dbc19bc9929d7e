#!/usr/bin/env bash
# Quick start, part 2: install everything the tests need, then lint, type-check and test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test
.venv/bin/ruff check src tests benchmarks
.venv/bin/ruff format --check src tests benchmarks
.venv/bin/mypy
# The coverage of src/ by the whole suite, printed at the end (modules fully covered left out).
exec .venv/bin/pytest -q --cov=scan2terrain --cov-report=term:skip-covered "$@"
