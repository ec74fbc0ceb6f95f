#!/usr/bin/env bash
# make mutation: cosmic-ray over mutation/cosmic-ray.toml in a copy of the tracked files (the
# copy imports as maglevgen through PYTHONPATH, ahead of the editable install), then the
# report in mutation/report.txt. Needs the `mutation` extra: pip install -e '.[mutation]'.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=${PYTHON:-$ROOT/.venv/bin/python}
BIN=$(dirname "$PY")
WORK=$(mktemp -d "${TMPDIR:-/tmp}/maglevgen-mutation.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
git ls-files -z --cached --others --exclude-standard | xargs -0 cp --parents -t "$WORK"
ln -s ../derive "$WORK/maglevgen/derive"
ln -s ../runtime "$WORK/maglevgen/runtime"
ln -s ../templates "$WORK/maglevgen/templates"
cd "$WORK"
export PYTHONPATH=$WORK PATH=$BIN:$PATH
"$BIN/cosmic-ray" init mutation/cosmic-ray.toml session.sqlite
"$PY" mutation/filter.py session.sqlite
"$BIN/cosmic-ray" exec mutation/cosmic-ray.toml session.sqlite
"$BIN/cr-report" --show-diff --surviving-only session.sqlite > "$ROOT/mutation/report.txt" || true
"$BIN/cr-report" session.sqlite | tail -3
cp session.sqlite "$ROOT/mutation/session.sqlite"
