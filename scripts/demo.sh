#!/usr/bin/env bash
# The main job on built-in defaults: install, render the demo scene and the shared autzen sample.
# The first run after an install compiles the numba kernels it needs (a spinner says so on a
# terminal); `.venv/bin/gigapoint compile` compiles all of them up front.
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS=all bash scripts/setup_env.sh
mkdir -p out
.venv/bin/gigapoint demo --points "${POINTS:-20000000}" -o out/demo.png --overwrite
if [ -f ../shared/data/autzen_trim.laz ]; then
  .venv/bin/gigapoint render ../shared/data/autzen_trim.laz -o out/autzen.png --stats --overwrite
fi
