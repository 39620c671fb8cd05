"""Where the derivative cut-off rule and the recommended fit stand, in simulation (`ident_opt.evaluation.cutoff_study`):
every kind of motion × sampling rate × noise factor, against the best cut-off in hindsight.

    .venv/bin/python benchmarks/cutoff_study.py [--seeds tuning|unseen|fresh] [--out results]

`tuning` seeds are the ones the rule was developed on; `unseen` ones were looked at for final tables (from stop
33 on); `fresh`, ten seeds, run once with the rule unchanged. Each writes results/cutoff_study_<seeds>.md (.csv,
.json, .png). About 3-4 min on 2 cores for a set of three seeds, 15 min for `fresh` (893 s measured).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ident_opt.evaluation import cutoff_study
from ident_opt.problem import load_problem
from ident_opt.report import cutoff_study as report

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    """Run the study on one seed set and write its report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", choices=tuple(cutoff_study.SEED_SETS), default="tuning")
    parser.add_argument("--out", default=str(ROOT / "results"))
    args = parser.parse_args()
    seeds = cutoff_study.SEED_SETS[args.seeds]
    problem = load_problem(ROOT / "problems" / "dfki_c0.toml")
    start = time.perf_counter()
    rows = cutoff_study.run(problem, seeds=seeds)
    for path in report.write(rows, Path(args.out), args.seeds, seeds, time.perf_counter() - start):
        print(path)


if __name__ == "__main__":
    main()
