#!/usr/bin/env bash
# make mutation: cosmic-ray over mutation/NAME.toml for each NAME given (default: every config
# but the before-score one). The mutants run on MUTATION_JOBS workers (default: every core),
# cosmic-ray's own http distributor: each worker is a `cosmic-ray http-worker` in a throw-away
# copy of the tracked files (the copy imports as maglevgen through PYTHONPATH, ahead of the
# editable install, so an interrupted run never leaves a mutant in the working tree), pinned to
# one core. Sessions go to mutation/sessions/NAME.sqlite; then mutation/score.py writes
# mutation/report.txt from every session there.
# MUTATION_REV=COMMIT copies that commit's files instead (the before score: its tests).
# MUTATION_RESUME=1 goes on with mutation/sessions/NAME.sqlite where it exists (only the
# mutants not yet run; valid while the mutated files are unchanged) instead of a new session.
# Needs the `mutation` extra: pip install -e '.[mutation]'. Runs niced: the machine is shared.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=${PYTHON:-$ROOT/.venv/bin/python}
BIN=$(dirname "$PY")
JOBS=${MUTATION_JOBS:-$(nproc)}
NAMES=("$@")
[ ${#NAMES[@]} -gt 0 ] || NAMES=(core damping allocation trim riccati model sympy_casadi)
mkdir -p "$ROOT/mutation/sessions"
TMP=$(mktemp -d "${TMPDIR:-/tmp}/maglevgen-mutation.XXXXXX")
PIDS=()
cleanup() { [ ${#PIDS[@]} -eq 0 ] || kill "${PIDS[@]}" 2>/dev/null || true; rm -rf "$TMP"; }
trap cleanup EXIT

copy_tree() {  # copy_tree DIR: the files to mutate and test, importable as maglevgen
  mkdir -p "$1"
  if [ -n "${MUTATION_REV:-}" ]; then
    git archive "$MUTATION_REV" | tar -x -C "$1"
  else
    git ls-files -z --cached --others --exclude-standard | xargs -0 cp --parents -t "$1"
  fi
  for d in derive runtime templates; do
    [ -e "$1/maglevgen/$d" ] || ln -s ../$d "$1/maglevgen/$d"
  done
}

# The workers: one per core, each in its own copy and on its own port.
URLS=()
for ((i = 0; i < JOBS; i++)); do
  W=$TMP/worker$i
  copy_tree "$W"
  PORT=$("$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  (cd "$W" && PYTHONPATH=$W PATH=$BIN:$PATH OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \
     exec taskset -c $((i % $(nproc))) nice -n 19 "$BIN/cosmic-ray" http-worker --port "$PORT" \
     > "$TMP/worker$i.log" 2>&1) &
  PIDS+=($!)
  URLS+=("'http://127.0.0.1:$PORT'")
done
for u in "${URLS[@]}"; do  # wait until each worker listens
  for _ in $(seq 100); do "$PY" - "$u" 2>/dev/null <<'PY' && break || sleep 0.2
import socket, sys, urllib.parse
u = urllib.parse.urlparse(sys.argv[1].strip("'"))
socket.create_connection((u.hostname, u.port), timeout=1).close()
PY
  done
done

for NAME in "${NAMES[@]}"; do
  S=$TMP/$NAME
  copy_tree "$S"
  cp mutation/filter.py "$S"/
  # The config as committed, with the http distributor over the workers.
  sed 's/^name = "local"$/name = "http"/' mutation/"$NAME".toml > "$S/$NAME.toml"
  printf '\n[cosmic-ray.distributor.http]\nworker-urls = [%s]\n' "$(IFS=,; echo "${URLS[*]}")" \
    >> "$S/$NAME.toml"
  (
    cd "$S"
    export PYTHONPATH=$S PATH=$BIN:$PATH
    if [ -n "${MUTATION_RESUME:-}" ] && [ -f "$ROOT/mutation/sessions/$NAME.sqlite" ]; then
      cp "$ROOT/mutation/sessions/$NAME.sqlite" session.sqlite
    else
      nice -n 19 "$BIN/cosmic-ray" init "$NAME.toml" session.sqlite
      nice -n 19 "$PY" filter.py session.sqlite
    fi
    nice -n 19 "$BIN/cosmic-ray" exec "$NAME.toml" session.sqlite || true
    cp session.sqlite "$ROOT/mutation/sessions/$NAME.sqlite"
  )
done
"$PY" mutation/score.py mutation/sessions/*.sqlite > mutation/report.txt
head -20 mutation/report.txt
