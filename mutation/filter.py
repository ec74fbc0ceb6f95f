"""Mark as skipped the mutants outside the operator set this project tests against.

cosmic-ray generates every binary-operator replacement (a + b -> a << b, a ^ b, ...); on SymPy
expressions those raise at once and only cost a test run each. Kept: the slips a person makes
writing the paper's equations (+ <-> -, * <-> /, ** <-> *, a dropped or added minus sign, a
changed number, a flipped comparison or boolean, a loop that does not run).
Usage: python mutation/filter.py SESSION.sqlite
"""

from __future__ import annotations

import re
import sys

from cosmic_ray.work_db import WorkDB, use_db
from cosmic_ray.work_item import WorkerOutcome, WorkResult

KEPT = re.compile(
    r"core/(ReplaceBinaryOperator_(Add_Sub|Sub_Add|Mul_Div|Div_Mul|Pow_Mul|Mul_Pow)"
    r"|ReplaceUnaryOperator_(USub_UAdd|Delete_USub)|NumberReplacer"
    r"|ReplaceComparisonOperator_(GtE_Lt|Gt_LtE|Lt_GtE|LtE_Gt|Eq_NotEq|NotEq_Eq)"
    r"|ReplaceAndWithOr|ReplaceOrWithAnd|ReplaceTrueWithFalse|ReplaceFalseWithTrue"
    r"|ZeroIterationForLoop|AddNot)$")


def main(session: str) -> None:
    kept = skipped = 0
    with use_db(session, WorkDB.Mode.open) as db:
        for item in list(db.pending_work_items):
            if all(KEPT.match(m.operator_name) for m in item.mutations):
                kept += 1
                continue
            db.set_result(item.job_id, WorkResult(output="operator not in the tested set",
                                                  worker_outcome=WorkerOutcome.SKIPPED))
            skipped += 1
    print(f"{kept} mutants to run, {skipped} skipped (operators outside the set)")


if __name__ == "__main__":
    main(sys.argv[1])
