#!/usr/bin/env bash
# Run a command inside the built FLAAIR environment (venv + colcon install), e.g.
#   scripts/in_env.sh python -m pytest tests
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -f "$ROOT/install/setup.bash" ] || [ ! -x "$ROOT/.venv/bin/python" ]; then
  echo "[flaair] the environment is not built yet; building it (scripts/setup_env.sh)" >&2
  "$ROOT/scripts/setup_env.sh" >&2
fi
# A command started from inside the environment (a test's or a graph's child) inherits it:
# sourcing colcon's setup again would only cost its helper's Python start.
if [ "${FLAAIR_ENV_SOURCED:-}" != "$ROOT" ]; then
  set +u
  # shellcheck disable=SC1091
  . "$ROOT/install/setup.bash"
  set -u
  export FLAAIR_ENV_SOURCED="$ROOT"
fi
export FLAAIR_CONFIG_DIR="${FLAAIR_CONFIG_DIR:-$ROOT/config}"
export FLAAIR_ROOT="$ROOT"
export MPLBACKEND="${MPLBACKEND:-Agg}"
exec "$@"
