# Sourced by scripts/demo and scripts/test: make .venv if missing and install irdetect into it.
# Usage: . scripts/_venv.sh [extra]   (extra: "test" installs the test extra)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3}"
if [ ! -x "$ROOT/.venv/bin/python" ]; then
  echo "creating $ROOT/.venv" >&2
  "$PY" -m venv "$ROOT/.venv"
fi
VPY="$ROOT/.venv/bin/python"
spec="$ROOT"
[ -n "${1:-}" ] && spec="$ROOT[$1]"
"$VPY" -m pip install --quiet --disable-pip-version-check -e "$spec" 2>&1 \
  | grep -v "is ignored: it is neither a file nor a directory" || true
if [ "${1:-}" = "test" ]; then
  # the IRSTD Pd / Fa reference (tests/test_irstd.py): it pins numpy<2, which must never
  # downgrade the numpy irdetect runs on, so no dependencies (the test extra has them)
  "$VPY" -m pip install --quiet --disable-pip-version-check --no-deps pyirstdmetrics==1.0.2 \
    2>&1 | grep -v "is ignored: it is neither a file nor a directory" || true
fi
