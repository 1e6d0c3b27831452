#!/usr/bin/env python3
"""What a `cosem session --json` run lost, triple by triple.

Reads the JSON lines of one or more sessions (files, or folders of
`*.jsonl`) and prints each session's summary figures; with `--lost`, every
triple (robot, peer, round) inside a meeting that is not a correct
`Converged`, leaving out each meeting's first 2 rounds, as the issue's
availability counts them: a meeting is a maximal run of rounds with
`overlap_true` >= 0.30, correct is `Converged` with `e_t` < 0.5 m and
`e_r` < 1 degree. The count of lost triples is checked against the
summary's `in_meetings - available`.

    cosem session --drift 1%,0.5 --seed 5 --label-noise network --json > s5.jsonl
    python3 tests/python/session_losses.py --lost s5.jsonl
"""
import argparse
import collections
import glob
import json
import os
import sys

MEETING = 0.30
SKIPPED = 2
STRICT = (0.5, 1.0)


def correct(r):
    return r["status"] == "Converged" and r.get("e_t", 1e9) < STRICT[0] and r.get("e_r", 1e9) < STRICT[1]


def read(path):
    records, summary = [], None
    with open(path) as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                d = json.loads(line)
            except json.JSONDecodeError as e:
                sys.exit(f"{path}:{n}: not JSON: {e}")
            if "summary" in d:
                summary = d["summary"]
            else:
                records.append(d)
    if summary is None:
        sys.exit(f"{path}: no summary line (the session did not finish?)")
    return records, summary


def lost(records):
    by = collections.defaultdict(dict)
    for r in records:
        by[(r["robot"], r["peer"])][r["round"]] = r
    out = []
    for pair in sorted(by):
        start = prev = None
        for rn in sorted(by[pair]):
            r = by[pair][rn]
            if (r.get("overlap_true") or 0.0) < MEETING:
                start = None
                continue
            if start is None or rn != prev + 1:
                start = rn
            prev = rn
            if rn - start >= SKIPPED and not correct(r):
                out.append((pair, rn, rn - start, r))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("paths", nargs="+", help="session JSON lines, or folders of *.jsonl")
    ap.add_argument("--lost", action="store_true", help="list the lost in-meeting triples")
    a = ap.parse_args()
    paths = []
    for p in a.paths:
        paths += sorted(glob.glob(os.path.join(p, "*.jsonl"))) if os.path.isdir(p) else [p]
    if not paths:
        sys.exit("no session files")
    total = collections.Counter()
    for p in paths:
        records, s = read(p)
        miss = lost(records)
        if len(miss) != s["in_meetings"] - s["available"]:
            sys.exit(f"{p}: {len(miss)} lost triples, but the summary says {s['in_meetings'] - s['available']}")
        p95 = s["update_bytes_ratio"][1] if s.get("update_bytes_ratio") else float("nan")
        cost = s.get("tracking_cost_ratio")
        print(
            f"{os.path.basename(p)}: wrong {s['wrong_converged']}, availability {s['availability']:.3f}"
            f" ({s['available']}/{s['in_meetings']}), first fix {s['first_fix_rounds']}, update p95 {p95:.3f},"
            f" cost {cost if cost is None else round(cost, 3)}"
        )
        for (i, j), rn, into, r in miss if a.lost else []:
            print(
                f"  ({i},{j}) round {rn} (+{into}) {r['status']} {r['kind']} fix {r['fix']}"
                f" e_t {r.get('e_t', float('nan')):.2f} e_r {r.get('e_r', float('nan')):.2f}"
                f" overlap_true {r['overlap_true']:.2f} agreement {r.get('agreement', float('nan')):.2f}"
                f" degeneracy {r.get('degeneracy', float('nan')):.4f}"
            )
        total["wrong"] += s["wrong_converged"]
        total["available"] += s["available"]
        total["in"] += s["in_meetings"]
    if len(paths) > 1:
        print(f"all: wrong {total['wrong']}, availability {total['available'] / max(1, total['in']):.3f}")


if __name__ == "__main__":
    main()
