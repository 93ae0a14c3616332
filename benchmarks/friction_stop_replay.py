"""Replay the triaxial step's stop rule (``geodem.cases.triaxial.past_peak``) on stored
stages: for each (drop, drop_strain), does every stage stop at the same peak as the rule it
was run with, and how many steps would it take?

    python benchmarks/friction_stop_replay.py DIR [DIR ...] [--ran-with 0.95 1.5]

DIR: folders searched for ``triaxial_curves.csv`` (a calibration's ``iterations/``). A
stage's run up to its stop does not depend on the rule, so a rule that stops a stored stage
inside its samples stops the real run at that sample with that peak; a rule that would not
have stopped within them is counted apart (it would have run on: unknown).
"""
import argparse
import csv
import itertools
from pathlib import Path

from geodem.cases.triaxial import past_peak

RULES = [(0.95, 1.5), (0.95, 1.25), (0.95, 1.1), (0.95, 1.0), (0.92, 1.1), (0.9, 1.0)]


def stages(path: Path):
    """The stages of one triaxial_curves.csv: lists of rows (columns as written)."""
    with open(path) as f:
        rows = [[float(v) for v in r] for r in list(csv.reader(f))[1:]]
    for _, group in itertools.groupby(rows, key=lambda r: r[0]):
        yield list(group)


def replay(rows, drop: float, drop_strain: float):
    """(peak deviator, index of the stopping sample or None) of the rule on ``rows``."""
    ipeak = 0
    for i in range(len(rows)):
        if rows[i][6] > rows[ipeak][6]:
            ipeak = i
        if past_peak(rows[:i + 1], ipeak, drop, drop_strain):
            return rows[ipeak][6], i
    return rows[ipeak][6], None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", type=Path)
    ap.add_argument("--ran-with", nargs=2, type=float, default=(0.95, 1.5),
                    metavar=("DROP", "DROP_STRAIN"))
    a = ap.parse_args()
    found = sorted({p for d in a.dirs for p in d.rglob("triaxial_curves.csv")})
    steps = dict.fromkeys(RULES, 0.0)
    moved = dict.fromkeys(RULES, 0)
    unknown = dict.fromkeys(RULES, 0)
    n = 0
    for rows in (s for p in found for s in stages(p)):
        ref, iref = replay(rows, *a.ran_with)
        if iref is None:  # stopped otherwise (max_strain, walls): not a drop to replay
            continue
        n += 1
        for rule in RULES:
            peak, i = replay(rows, *rule)
            if i is None:
                unknown[rule] += 1
                i = len(rows) - 1
            moved[rule] += peak != ref
            steps[rule] += rows[i][2] - rows[0][2]
    print(f"{n} stages stopped by the drop rule ({a.ran_with[0]}, {a.ran_with[1]} x), "
          f"{len(found)} files")
    print("drop  drop_strain  steps/ran  another peak  not stopped within the samples")
    for rule in RULES:
        print(f"{rule[0]:<5} {rule[1]:<12} {steps[rule] / steps[tuple(a.ran_with)]:<10.3f} "
              f"{moved[rule]:<13d} {unknown[rule]}")


if __name__ == "__main__":
    main()
