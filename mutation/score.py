"""Per-module mutation score and surviving mutants of cosmic-ray sessions (mutation/report.txt).

Usage: python mutation/score.py SESSION.sqlite... ; one table row per session (run, killed,
survived, of which timeouts, and not run), then each survivor's diff.
"""

from __future__ import annotations

import sys
from pathlib import Path

from cosmic_ray.work_db import WorkDB, use_db
from cosmic_ray.work_item import TestOutcome, WorkerOutcome


def main(sessions: list[str]) -> None:
    rows, diffs = [], []
    for session in sessions:
        name = Path(session).stem
        with use_db(session, WorkDB.Mode.open) as db:
            done = list(db.completed_work_items)
            pending = sum(1 for _ in db.pending_work_items)
        run = [(i, r) for i, r in done if r.worker_outcome != WorkerOutcome.SKIPPED]
        timeouts = sum(r.output == "timeout" for _, r in run)  # cosmic-ray: killed
        survived = [(i, r) for i, r in run if r.test_outcome == TestOutcome.SURVIVED]
        killed = len(run) - len(survived)
        score = f"{100 * killed / len(run):.1f} %" if run else "-"
        rows.append(f"{name:16s} {len(run):5d} {killed:7d} {len(survived):9d} {timeouts:9d} "
                    f"{pending:8d}  {score}")
        for item, result in survived:
            (m,) = item.mutations
            diffs.append(f"[{name}] {m.module_path}:{m.start_pos[0]} {m.operator_name} "
                         f"{m.occurrence}\n{result.diff}")
    print("session            run  killed  survived  timeouts  not run  score")
    print("(timeouts: killed by the per-mutant time limit; not run: pending when stopped)")
    print("\n".join(rows))
    print("\nSurviving mutants\n")
    print("\n".join(diffs))


if __name__ == "__main__":
    main(sys.argv[1:])
