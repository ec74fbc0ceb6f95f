"""Re-run the surviving mutants of a session against the current tests.

After tests are added for survivors, each surviving (module, operator, occurrence) is applied
again in a throw-away copy (as mutation/run.sh makes) and the test command run once more.
Usage: python mutation/recheck.py SESSION.sqlite WORK_COPY "TEST COMMAND" [DONE.txt]
Prints one line per mutant: killed / survived, module, operator, occurrence; the mutants
already listed in DONE.txt (an earlier output of this script) are left out.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from cosmic_ray.work_db import WorkDB, use_db
from cosmic_ray.work_item import TestOutcome


def main(session: str, work: str, command: str, done: str | None = None) -> None:
    seen = set()
    if done:
        seen = {tuple(line.split()[1:4]) for line in Path(done).read_text().splitlines()}
    with use_db(session, WorkDB.Mode.open) as db:
        survivors = [item for item, result in db.completed_work_items
                     if result.test_outcome == TestOutcome.SURVIVED]
    cr = str(Path(sys.executable).with_name("cosmic-ray"))
    for item in survivors:
        (mut,) = item.mutations
        if (str(mut.module_path), mut.operator_name, str(mut.occurrence)) in seen:
            continue
        proc = subprocess.run([cr, "mutate-and-test", str(mut.module_path), mut.operator_name,
                               str(mut.occurrence), command], cwd=work, capture_output=True,
                              text=True)
        outcome = "killed" if '"killed"' in proc.stdout else \
            "survived" if '"survived"' in proc.stdout else "error"
        print(f"{outcome:9s} {mut.module_path} {mut.operator_name} {mut.occurrence} "
              f"line {mut.start_pos[0]}", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:5])
