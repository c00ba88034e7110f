#!/usr/bin/env bash
# The whole test suite: installs what it needs (system packages when run as root), checks the
# import layering (import-linter) and lints (ruff), then runs pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  need=""
  command -v chromium >/dev/null || need="$need chromium"
  command -v npm >/dev/null || need="$need npm"  # tests/integration/test_lod_browser.py: potree-core + three.js from npm
  [ -e /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] || ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || need="$need mesa-vulkan-drivers"
  dpkg -s libegl1 libgl1 libgl1-mesa-dri libgles2 >/dev/null 2>&1 || need="$need libegl1 libgl1 libgl1-mesa-dri libgles2"
  if [ -n "$need" ]; then
    # another apt/dpkg (an unattended upgrade) may hold the lock: wait for it rather than fail
    apt-get -o DPkg::Lock::Timeout=600 update -qq >/dev/null \
      && DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=600 install -y -qq $need >/dev/null
  fi
fi
EXTRAS="all,test" bash scripts/setup_env.sh
# the layering (docs/architecture.md, [tool.importlinter] in pyproject.toml) and the linter first
.venv/bin/lint-imports --no-cache >/dev/null || { .venv/bin/lint-imports --no-cache; exit 1; }
.venv/bin/ruff check --quiet src tests benchmarks
exec .venv/bin/python -m pytest -q "$@"
