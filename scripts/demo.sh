#!/usr/bin/env bash
# The main job: set up (idempotent), then run the demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python baselines/demo.py "$@"
