#!/usr/bin/env python3
"""The verdict's operating points (docs/evaluation.md, "The verdict").

Reads `cosem eval --json` files of true pairs (grid or --global) and
`cosem eval --negatives --min-agreement 0 --json` files, and prints, for
each threshold on the agreement, the true pairs' answers still accepted and
the negatives accepted, with the margin between the weakest true answer and
the worst negative.

    python3 tests/verdict/table.py --positives POS.json... --negatives NEG.json...
"""
import argparse
import json


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--positives", nargs="+", required=True)
    p.add_argument("--negatives", nargs="+", required=True)
    p.add_argument("--thresholds", default="0.2,0.25,0.3,0.35,0.4,0.45,0.5,0.55,0.6")
    a = p.parse_args()
    true_answers = []  # agreement of each strict success
    starts = 0
    for f in a.positives:
        for r in json.load(open(f))["results"]:
            starts += 1
            if r["status"] == "Converged" and r["e_t"] < 0.5 and r["e_r"] < 1.0:
                true_answers.append(r["agreement"])
    negatives = []  # agreement of each negative the other checks let through
    cases = 0
    for f in a.negatives:
        for c in json.load(open(f))["results"]:
            cases += 1
            if c["status"] == "Converged":
                negatives.append(c["agreement"])
    print(f"true pairs: {starts} starts, {len(true_answers)} strict successes without the agreement check")
    print(f"negatives: {cases} cases, {len(negatives)} Converged without the agreement check")
    print("| agreement threshold | true answers kept | false accepts | weakest true kept - worst negative accepted |")
    print("|---|---|---|---|")
    for t in [float(x) for x in a.thresholds.split(",")]:
        kept = [v for v in true_answers if v >= t]
        fa = [v for v in negatives if v >= t]
        weakest = min(kept) if kept else float("nan")
        worst = max(fa) if fa else None
        margin = f"{weakest:.3f} - {worst:.3f}" if worst is not None else f"{weakest:.3f} - (none)"
        print(f"| {t:.2f} | {100.0 * len(kept) / max(1, starts):.1f}% | {len(fa)} of {cases} | {margin} |")
    worst_all = max(negatives) if negatives else float("nan")
    print(f"weakest true answer {min(true_answers):.3f}; worst negative {worst_all:.3f}")


if __name__ == "__main__":
    main()
