#!/usr/bin/env bash
# The test command: set up (idempotent), then run the test suite on the real simulator and renderer.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
