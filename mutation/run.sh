#!/usr/bin/env bash
# make mutation: cosmic-ray over mutation/NAME.toml for each NAME given (default: every config
# but the before-score one), each in a throw-away copy of the tracked files (the copy imports
# as maglevgen through PYTHONPATH, ahead of the editable install, so an interrupted run never
# leaves a mutant in the working tree). Sessions go to mutation/sessions/NAME.sqlite; then
# mutation/score.py writes mutation/report.txt from every session there.
# MUTATION_REV=COMMIT copies that commit's files instead (the before score: its tests).
# Needs the `mutation` extra: pip install -e '.[mutation]'. Runs niced: the machine is shared.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=${PYTHON:-$ROOT/.venv/bin/python}
BIN=$(dirname "$PY")
NAMES=("$@")
[ ${#NAMES[@]} -gt 0 ] || NAMES=(core damping allocation trim riccati model sympy_casadi)
mkdir -p "$ROOT/mutation/sessions"
for NAME in "${NAMES[@]}"; do
  WORK=$(mktemp -d "${TMPDIR:-/tmp}/maglevgen-mutation.XXXXXX")
  if [ -n "${MUTATION_REV:-}" ]; then
    git archive "$MUTATION_REV" | tar -x -C "$WORK"
  else
    git ls-files -z --cached --others --exclude-standard | xargs -0 cp --parents -t "$WORK"
  fi
  cp mutation/"$NAME".toml mutation/filter.py "$WORK"/  # the current config and filter
  for d in derive runtime templates; do
    [ -e "$WORK/maglevgen/$d" ] || ln -s ../$d "$WORK/maglevgen/$d"
  done
  (
    cd "$WORK"
    export PYTHONPATH=$WORK PATH=$BIN:$PATH
    nice -n 19 "$BIN/cosmic-ray" init "$NAME.toml" session.sqlite
    nice -n 19 "$PY" filter.py session.sqlite
    nice -n 19 "$BIN/cosmic-ray" exec "$NAME.toml" session.sqlite || true
    cp session.sqlite "$ROOT/mutation/sessions/$NAME.sqlite"
  )
  rm -rf "$WORK"
done
"$PY" mutation/score.py mutation/sessions/*.sqlite > mutation/report.txt
head -20 mutation/report.txt
