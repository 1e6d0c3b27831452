#!/usr/bin/env bash
# Regenerates docs/results.md from `--json` runs of the release binary on
# the real data ($COSEM_DATA, default ../shared/data), stamped with the
# commit and the machine: no figure on that page is typed by hand.
#
#   bash docs/results.sh            # host figures (about 5 minutes on 2 cores)
#   bash docs/results.sh --boards   # and the two robots on emulated boards
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="${COSEM_DATA:-../shared/data}"
BOARDS=0
[ "${1:-}" = "--boards" ] && BOARDS=1
COMMIT="$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- core host || echo '+changes')"
cargo build --release --locked -p cosem-host >/dev/null 2>&1
OUT="$(mktemp -d)"
trap 'rm -rf "$OUT"' EXIT
# The binary of this commit, whatever is built while the runs go on.
cp ./target/release/cosem "$OUT/cosem"
C="$OUT/cosem"

PAIRS=("kitti00 0:5 5:10" "kitti07 0:5 5:10" "kitti00-loop 52:53 4501:4502" "kitti08-loop 720:721 1500:1501")
for p in "${PAIRS[@]}"; do
  set -- $p
  [ -d "$DATA/$1" ] || { echo "skipping $1: not in $DATA" >&2; continue; }
  $C eval --data "$DATA/$1" --a "$2" --b "$3" --voxel 0.2 --grid-stride 2 --threads 1 --json "$OUT/grid-$1.json" >/dev/null
  $C eval --data "$DATA/$1" --a "$2" --b "$3" --voxel 0.5 --global --json "$OUT/global-gt-$1.json" >/dev/null
  $C eval --data "$DATA/$1" --a "$2" --b "$3" --voxel 0.5 --global --label-noise network:2 --seed 3 --json "$OUT/global-$1.json" >/dev/null
  $C map --data "$DATA/$1" --frames "$2" --voxel 0.2 -o "$OUT/map-$1.cmap" >/dev/null
  $C info "$OUT/map-$1.cmap" --json >"$OUT/info-$1.json"
done
# Benchmarks on kitti00 (their defaults): mapping, the wire encoding, the
# link over the seeded lossy line simulation.
if [ -d "$DATA/kitti00" ]; then
  COSEM_DATA="$DATA" $C bench map --json "$OUT/bench-map.json" >/dev/null
  COSEM_DATA="$DATA" $C bench wire --json "$OUT/bench-wire.json" >/dev/null
  COSEM_DATA="$DATA" $C bench link --seeds 10 --json "$OUT/bench-link.json" >/dev/null
  COSEM_DATA="$DATA" $C bench link --seeds 10 --mix byte=1 --json "$OUT/bench-link-byte.json" >/dev/null
  COSEM_DATA="$DATA" $C bench link --seeds 3 --error-rates 0,0.01,0.05 --half-duplex --json "$OUT/bench-link-half.json" >/dev/null
fi
# Camera labels on synthetic streets (perfect, corrupted, probabilities).
$C bench label --seeds 1,2,3,4,5,6,7,8,9,10 --json "$OUT/bench-label.json" >/dev/null
# Two `cosem link` processes through `cosem relay` (each direction paced to
# 115200 baud, seeded errors), kitti00's robot maps: wall time from start
# to the exit of both, match included.
relay_run() { # tag error-rate seed (substituted, dropped, duplicated alike)
  local log="$OUT/relay-$1-$3.log" a0 a1 t0 t1 rp lp
  $C relay --baud 115200 --error-rate "$2" --mix byte=1,drop=1,dup=1 --seed "$3" >"$log" 2>&1 &
  rp=$!
  for _ in $(seq 200); do grep -q "relay on" "$log" 2>/dev/null && break; sleep 0.05; done
  read -r _ _ a0 a1 <"$log"
  t0=$(date +%s.%N)
  $C link --map "$OUT/robot-a.cmap" --tcp "$a0" --robot-id 0 --baud 115200 --json >"$OUT/relay-$1-$3-a.json" &
  lp=$!
  $C link --map "$OUT/robot-b.cmap" --tcp "$a1" --robot-id 1 --baud 115200 --json >"$OUT/relay-$1-$3-b.json" || true
  wait "$lp" || true
  t1=$(date +%s.%N)
  wait "$rp" || true
  echo "{\"tag\": \"$1\", \"error_rate\": $2, \"seed\": $3, \"wall_s\": $(awk "BEGIN {print $t1 - $t0}")}" \
    >"$OUT/relay-$1-$3.json"
}
if [ -d "$DATA/kitti00" ]; then
  $C map --data "$DATA/kitti00" --frames 0:5 --voxel 0.5 --max-range 25 -o "$OUT/robot-a.cmap" >/dev/null
  $C map --data "$DATA/kitti00" --frames 5:10 --voxel 0.5 --max-range 25 -o "$OUT/robot-b.cmap" >/dev/null
  for r in "clean 0" "e1 0.01" "e5 0.05" "e10 0.1" "e20 0.2"; do
    set -- $r
    for s in 1 2 3; do relay_run "$1" "$2" "$s"; done
  done
fi
NEG=()
for n in kitti00-loop:88:89 kitti00-loop:850:851 kitti07:0:1 kitti08-loop:720:721 kitti00-loop:4501:4502; do
  [ -d "$DATA/${n%%:*}" ] && NEG+=("$DATA/$n")
done
if [ "${#NEG[@]}" -ge 2 ]; then
  $C eval --negatives "${NEG[@]}" --voxel 0.5 --label-noise network --seed 4 --json "$OUT/negatives.json" >/dev/null
fi
# The verdict's operating points (tests/verdict/table.py): true pairs and
# pairs that cannot match, all with the agreement check off, so the table
# can say what each threshold keeps and lets through.
V="$OUT/verdict"
mkdir -p "$V"
$C synth --seed 21 --frames 10 --out "$OUT/street10" >/dev/null
POS=("kitti00 0:5 5:10" "kitti07 0:5 5:10" "kitti00 0:1 5:6" "kitti00-loop 52:53 4501:4502"
     "kitti08-loop 720:721 1500:1501" "kitti00-loop 52:53 88:89")
k=0
for p in "${POS[@]}" "street10 0:5 5:10"; do
  set -- $p
  d="$DATA/$1"; [ "$1" = street10 ] && d="$OUT/street10"
  [ -d "$d" ] || continue
  for noise in none network network:2; do
    k=$((k + 1))
    $C eval --data "$d" --a "$2" --b "$3" --voxel 0.2 --grid-stride 2 --min-agreement 0 --label-noise "$noise" \
      --json "$V/pos-grid-$k.json" >/dev/null
    $C eval --data "$d" --a "$2" --b "$3" --voxel 0.2 --global --min-agreement 0 --label-noise "$noise" \
      --json "$V/pos-global-$k.json" >/dev/null
  done
done
PLACES=("${NEG[@]}")
for seed in 31 32 33 34 35 36; do
  $C synth --seed "$seed" --frames 1 --out "$OUT/place$seed" >/dev/null
  PLACES+=("$OUT/place$seed:0:1")
done
for noise in none network; do
  $C eval --negatives "${PLACES[@]}" --voxel 0.2 --min-agreement 0 --label-noise "$noise" \
    --json "$V/neg-$noise.json" >/dev/null
done
python3 tests/verdict/table.py --positives "$V"/pos-*.json --negatives "$V"/neg-*.json \
  --thresholds 0.25,0.3,0.35,0.4,0.45,0.5,0.6,0.7 >"$OUT/verdict.md"
# Teams on the host (exit code 5 when a robot is unplaced: expected here).
K0="$DATA/kitti00"
if [ -d "$K0" ] && [ -d "$DATA/kitti07" ]; then
  MIXED=(--robot "$K0:0:3" --robot "$K0:3:6" --robot "$K0:6:10" --robot "$DATA/kitti07:0:3")
  $C team "${MIXED[@]}" --json >"$OUT/team-mixed.json" || true
  $C team "${MIXED[@]}" --inject-false-match 0,1 --json >"$OUT/team-injected.json" || true
fi
if [ -d "$K0" ] && [ -d "$DATA/kitti08-loop" ]; then
  L8="$DATA/kitti08-loop"
  $C team --robot "$K0:0:3" --robot "$K0:3:6" --robot "$L8:720:721" --robot "$L8:1500:1501" --json \
    >"$OUT/team-groups.json" || true
fi
# A team on data the project makes itself: a synthetic street cut in eight.
$C synth --seed 21 --frames 24 --out "$OUT/street" >/dev/null
EIGHT=()
for k in 0 3 6 9 12 15 18 21; do EIGHT+=(--robot "$OUT/street:$k:$((k + 3))"); done
$C team "${EIGHT[@]}" --json >"$OUT/team-street8.json" || true
if [ "$BOARDS" = 1 ] && [ -d "$K0" ]; then
  $C robots --data "$K0" --a 0:5 --b 5:10 --json >"$OUT/robots-prior.json" || true
  $C robots --data "$K0" --a 0:5 --b 5:10 --no-prior --json >"$OUT/robots-noprior.json" || true
  $C robots --data "$K0" --a 0:5 --b 5:10 --board-b stm32f405-sender --json >"$OUT/robots-stm32f405.json" || true
  # Both robots on the STM32F405 (192 KiB, 0.7 m voxels): every pair of the
  # pipeline table.
  S2=(--board-a stm32f405 --board-b stm32f405)
  $C robots --data "$K0" --a 0:5 --b 5:10 "${S2[@]}" --json >"$OUT/robots-stm32-prior.json" || true
  $C robots --data "$K0" --a 0:5 --b 5:10 --no-prior "${S2[@]}" --json >"$OUT/stm32-kitti00.json" || true
  $C robots --data "$K0" --a 0:5 --b 5:10 --no-prior --label-noise network "${S2[@]}" --json \
    >"$OUT/stm32-kitti00-network.json" || true
  if [ -d "$DATA/kitti00-loop" ]; then
    $C robots --data "$DATA/kitti00-loop" --a 52:53 --b 4501:4502 --no-prior "${S2[@]}" --json >"$OUT/stm32-loop00.json" || true
    $C robots --data "$DATA/kitti00-loop" --a 88:89 --b 850:851 --no-prior "${S2[@]}" --json >"$OUT/stm32-apart.json" || true
    $C robots --data "$DATA/kitti00-loop" --a 88:89 --b 850:851 --no-prior --label-noise network "${S2[@]}" --json \
      >"$OUT/stm32-apart-network.json" || true
  fi
  [ -d "$DATA/kitti08-loop" ] && { $C robots --data "$DATA/kitti08-loop" --a 720:721 --b 1500:1501 --no-prior "${S2[@]}" \
    --json >"$OUT/stm32-loop08.json" || true; }
  $C team --on-board --robot "$K0:0:3" --robot "$K0:3:6" --robot "$K0:6:10" --json >"$OUT/team-boards.json" || true
  $C team --on-board --board stm32f405 --robot "$K0:0:3" --robot "$K0:3:6" --robot "$K0:6:10" --json \
    >"$OUT/team-stm32.json" || true
  # The onboard pipeline per robot, no prior: overlapping pairs, the pair
  # that shares nothing, and a network's labels.
  $C robots --data "$K0" --a 0:5 --b 5:10 --no-prior --label-noise network --json >"$OUT/pipeline-kitti00-network.json" || true
  L0="$DATA/kitti00-loop"
  if [ -d "$L0" ]; then
    $C robots --data "$L0" --a 52:53 --b 4501:4502 --no-prior --json >"$OUT/pipeline-loop00.json" || true
    $C robots --data "$L0" --a 88:89 --b 850:851 --no-prior --json >"$OUT/pipeline-apart.json" || true
    $C robots --data "$L0" --a 88:89 --b 850:851 --no-prior --label-noise network --json >"$OUT/pipeline-apart-network.json" || true
  fi
  [ -d "$DATA/kitti08-loop" ] && { $C robots --data "$DATA/kitti08-loop" --a 720:721 --b 1500:1501 --no-prior --json \
    >"$OUT/pipeline-loop08.json" || true; }
fi

MACHINE="$(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(free -g | awk '/Mem/ {print $2}') GiB"
python3 - "$OUT" "$COMMIT" "$MACHINE" "$(date -u +%Y-%m-%d)" >docs/results.md <<'PY'
import json, os, sys
from collections import Counter
out, commit, machine, day = sys.argv[1:5]
def load(name):
    p = os.path.join(out, name)
    return json.load(open(p)) if os.path.exists(p) else None
print("# Results (generated)\n")
print(f"Generated by `docs/results.sh` at commit `{commit}` on {day}, on {machine}.")
print("Every figure below is read from the JSON of the command shown; rerun the script to refresh them.")
print("Times are wall-clock on this machine as it was (other jobs may have run beside); instruction counts are exact.\n")
g0 = load("grid-kitti00.json") or {"starts": "?"}
n_global = ((load("global-gt-kitti00.json") or {}).get("methods", {}).get("cosem", {}) or {}).get("starts", "?")
print(f"## Matching, the paper's grid (every 2nd value: {g0['starts']} starts), 0.2 m, cosem, 6-DoF, one thread\n")
print("`cosem eval --data D --a A --b B --voxel 0.2 --grid-stride 2 --threads 1 --json`\n")
print("| pair | A / B voxels | strict | e_t median | e_r median | ms per match | map file bytes per voxel (A) |")
print("|---|---|---|---|---|---|---|")
for name in ["kitti00", "kitti07", "kitti00-loop", "kitti08-loop"]:
    g, i = load(f"grid-{name}.json"), load(f"info-{name}.json")
    if not g:
        continue
    m = g["methods"]["cosem"]
    print(f"| {name} | {g['maps']['a_voxels']:,} / {g['maps']['b_voxels']:,} | {100*m['success_strict']:.1f}% | "
          f"{m['et_median_m']:.3f} m | {m['er_median_deg']:.3f} deg | {m['time_ms_median']:.1f} | "
          f"{i['bytes_per_voxel']:.2f} |")
print("\n## Prior-free, 0.5 m: ground-truth labels and a network's label errors (severity 2)\n")
print("`cosem eval --data D --a A --b B --voxel 0.5 --global [--label-noise network:2 --seed 3] --json` "
      "(36 headings x 10 offsets up to 50 m, no prior)\n")
print("| pair | labels | starts | strict | e_t median | e_r median | agreement median |")
print("|---|---|---|---|---|---|---|")
for name in ["kitti00", "kitti07", "kitti00-loop", "kitti08-loop"]:
    for file, labels in [(f"global-gt-{name}.json", "ground truth"), (f"global-{name}.json", "network:2 (seed 3)")]:
        g = load(file)
        if not g:
            continue
        m = g["methods"]["cosem"]
        agree = f"{m['agreement_median']:.3f}" if m.get("agreement_median") is not None else "-"
        print(f"| {name} | {labels} | {m['starts']} | {100*m['success_strict']:.1f}% | {m['et_median_m']:.3f} m | "
              f"{m['er_median_deg']:.3f} deg | {agree} |")
if os.path.exists(os.path.join(out, "verdict.md")):
    print("\n## The verdict's operating points, 0.2 m, the agreement check off\n")
    print(f"True pairs: every strict success of `cosem eval --grid-stride 2` ({g0['starts']} starts) and `--global` ({n_global}) on kitti00 "
          "0:5/5:10, kitti07 0:5/5:10, kitti00 single scans 0/5, kitti00-loop 52/4501, kitti08-loop 720/1500, "
          "kitti00-loop 52/88 (30 m apart) and a synthetic street, each with ground-truth labels, `--label-noise network` "
          "and `network:2`, all with `--min-agreement 0`. Pairs that cannot match: `cosem eval --negatives --min-agreement 0` "
          "over the shared data's places that do not overlap and six synthetic streets (alike by construction), "
          "with and without network noise. `tests/verdict/table.py` over those JSON files (a start that is no strict "
          "success without the check counts as not kept at any threshold: the 30 m pair with a network's labels is "
          "NoOverlap from every start):\n")
    lines = open(os.path.join(out, "verdict.md")).read().rstrip().split("\n")
    table = [l for l in lines if l.startswith("|")]
    print("\n".join(l for l in lines if not l.startswith("|")) + "\n")
    print("\n".join(table))
b = load("bench-map.json")
if b:
    print("\n## Mapping and the map file, kitti00 frames 0:10, 0.2 m, one thread\n")
    print("`cosem bench map --json` (median of 5 runs)\n")
    print(f"{b['points']:,} points read, {b['fused']:,} labelled points fused into {b['voxels']:,} voxels at "
          f"{b['fused'] / b['insert_s'] / 1e6:.1f} M points/s ({b['classify_insert_s'] * 1e3 / 10:.1f} ms per scan "
          f"with classifying); map file {b['file_bytes']:,} bytes, {b['file_bytes'] / b['voxels']:.2f} bytes per voxel.")
w = load("bench-wire.json")
if w:
    print("\n## The wire encoding, kitti00 frames 0:10, 0.2 m, one thread\n")
    print("`cosem bench wire --json` (median of 5 runs, chunks as on the link)\n")
    print(f"{w['voxels']:,} voxels in {w['bytes'][0]:,} bytes ({w['bytes'][0] / w['voxels']:.2f} bytes per voxel, "
          f"{w['bytes'][1]} chunks); encode {w['voxels'] / w['encode_s'] / 1e6:.1f} M voxels/s, "
          f"decode {w['voxels'] / w['decode_s'] / 1e6:.1f} M voxels/s.")
def link_table(l, title, what):
    print(f"\n## {title}\n")
    print(what + "\n")
    print("| byte errors | delivered | both maps through (median, worst) | goodput | capacity bound | without FEC at most | retransmissions (median) |")
    print("|---|---|---|---|---|---|---|")
    for r in l:
        print(f"| {100 * r['rate']:.0f}% | {r['delivered'][0]}/{r['delivered'][1]} | {r['median_s'][0]:.2f} s, {r['worst_s']:.2f} s | "
              f"{100 * r['goodput']:.0f}% | {100 * r.get('capacity', 0):.0f}% | {100 * r['bound'][0]:.0f}% | {r['retransmissions']:.0f} |")
sim = ("kitti00's robot maps, 0:5 and 5:10 at 0.5 m within 25 m; simulated time; capacity: a line substituting that "
       "share of its bytes, 8 - H(p) - p log2 255 bits a byte, the floor for drops and duplicates")
l = load("bench-link.json")
if l:
    link_table(l, "The link over a simulated lossy line, kitti00 robot maps, 115200 baud, both ways at once",
               f"`cosem bench link --seeds 10 --json` ({sim}; bytes substituted, dropped and duplicated alike)")
l = load("bench-link-byte.json")
if l:
    link_table(l, "The same, substituted bytes only",
               f"`cosem bench link --seeds 10 --mix byte=1 --json` ({sim})")
l = load("bench-link-half.json")
if l:
    link_table(l, "The same on a half-duplex line (one map after the other, in bursts)",
               f"`cosem bench link --seeds 3 --error-rates 0,0.01,0.05 --half-duplex --json` ({sim}; substituted, dropped and duplicated alike)")
rl = {}
for f in sorted(os.listdir(out)):
    if f.startswith("relay-") and f.count("-") == 2 and f.endswith(".json"):
        r = load(f)
        side = [load(f[:-5] + "-a.json"), load(f[:-5] + "-b.json")]
        rl.setdefault(r["tag"], []).append((r, side))
if rl:
    print("\n## Two link processes through a paced lossy relay, kitti00 robot maps, 115200 baud\n")
    print("`cosem relay --error-rate P --mix byte=1,drop=1,dup=1 --seed S` between two `cosem link --baud 115200 --json` "
          "(0:5 and 5:10 at 0.5 m within 25 m); wall time from start to the exit of both, match included. Each damaged "
          "byte is substituted, dropped or duplicated, a third each.\n")
    print("| byte errors | wall time per seed | vs clean (median) | delivered whole | the clean line's transforms |")
    print("|---|---|---|---|---|")
    def tf(x):
        return [round(v, 4) for v in ((x or {}).get("match") or {}).get("transform", [])]
    clean = rl.get("clean", [])
    base = sorted(r["wall_s"] for r, _ in clean)[len(clean) // 2] if clean else None
    ref = [tf(s) for s in clean[0][1]] if clean else None
    for tag, rate in (("clean", "0"), ("e1", "1%"), ("e5", "5%"), ("e10", "10%"), ("e20", "20%")):
        runs = rl.get(tag)
        if not runs:
            continue
        walls = [r["wall_s"] for r, _ in runs]
        whole = sum(1 for _, s in runs if all(x and x.get("voxels_received") is not None and x.get("voxels_received") == y.get("voxels_sent")
                                             for x, y in ((s[0], s[1]), (s[1], s[0])) if x and y) and all(s))
        same = sum(1 for _, s in runs if ref and [tf(x) for x in s] == ref)
        ratio = f"{sorted(walls)[len(walls) // 2] / base:.1f}x" if base else "-"
        print(f"| {rate} | {', '.join(f'{w:.1f}' for w in walls)} s | {ratio} | {whole}/{len(runs)} | {same}/{len(runs)} |")
bl = load("bench-label.json")
if bl:
    print("\n## Camera labels on synthetic streets, Cityscapes ids\n")
    seeds = sorted({r["seq"] for r in bl})
    print(f"`cosem bench label --seeds 1..{len(seeds)} --json` (synthetic streets of 10 frames, A = 0:5, B = 5:10, "
          "125 starts of the paper's grid); agreement over the points camera 2 sees, in brackets as Cityscapes' "
          "classes can say it (a trunk seen as vegetation agrees)\n")
    print("| labels | agreement with the truth | strict success | labelling (M points/s) |")
    print("|---|---|---|---|")
    for name in dict.fromkeys(r["labels"] for r in bl):
        rows = [r for r in bl if r["labels"] == name]
        rng = lambda k: (f"{100 * min(r[k] for r in rows):.1f}-{100 * max(r[k] for r in rows):.1f}%"
                         if rows[0][k] is not None else "-")
        strict = ("100% on every seed" if all(r["strict"] == 1.0 for r in rows)
                  else f"{100 * min(r['strict'] for r in rows):.1f}-{100 * max(r['strict'] for r in rows):.1f}%")
        rate = (f"{min(r['points_per_s'] for r in rows) / 1e6:.0f}-{max(r['points_per_s'] for r in rows) / 1e6:.0f}"
                if rows[0]["points_per_s"] else "-")
        agree = f"{rng('agreement')} ({rng('agreement_in_set')})" if rows[0]["agreement"] is not None else "-"
        print(f"| {name} | {agree} | {strict} | {rate} |")
n = load("negatives.json")
if n:
    print("\n## Pairs that cannot match (network labels), 0.5 m\n")
    print("`cosem eval --negatives ... --voxel 0.5 --label-noise network --seed 4 --json`\n")
    print(f"{len(n['places'])} places, {n['pairs']} ordered pairs, {n['cases']} matches (no prior, identity, random priors): "
          f"**{n['false_accepts']} false accepts**, largest agreement {n['agreement_max']:.3f} (the verdict's threshold: 0.40).")
STAGES = ("map_instructions", "prepare_instructions", "locate_instructions", "match_instructions")
def total(x):
    """A robot's instructions over the whole onboard pipeline."""
    return sum(x.get(k, 0) for k in STAGES)
TITLES = {
    "prior": ("a prior", "`cosem robots --data kitti00 --a 0:5 --b 5:10 --json`"),
    "noprior": ("no prior", "`cosem robots --data kitti00 --a 0:5 --b 5:10 --no-prior --json`"),
    "stm32f405": ("a prior, robot B on an STM32F405 as a sender (it sends its map and is told the result)",
                  "`cosem robots --data kitti00 --a 0:5 --b 5:10 --board-b stm32f405-sender --json`"),
    "stm32-prior": ("a prior, both robots on STM32F405s (192 KiB each, 0.7 m voxels)",
                    "`cosem robots --data kitti00 --a 0:5 --b 5:10 --board-a stm32f405 --board-b stm32f405 --json`"),
}
for kind in ["prior", "noprior", "stm32f405", "stm32-prior"]:
    r = load(f"robots-{kind}.json")
    if not r:
        continue
    title, command = TITLES[kind]
    print(f"\n## Two robots on emulated boards, kitti00 0:5 / 5:10, {title}\n")
    print(f"{command}\n")
    print("| robot | status | e_t | e_r | voxels | bytes sent / received | instructions (map + prepare + locate + match) | static RAM + peak stack |")
    print("|---|---|---|---|---|---|---|---|")
    for x in r["robots"]:
        print(f"| {x['id']} ({x['board']}) | {x['status']} | {x['e_t']:.3f} m | {x['e_r']:.3f} deg | {x['map_voxels']:,} | "
              f"{x['bytes_sent']:,} / {x['bytes_received']:,} | "
              f"{total(x)/1e6:.0f} M | {x['static_ram_bytes']:,} + {x['peak_stack_bytes']:,} B |")

PIPELINES = [
    ("robots-noprior", "kitti00 0:5 / 5:10"),
    ("pipeline-kitti00-network", "kitti00 0:5 / 5:10, network labels"),
    ("pipeline-loop08", "kitti08-loop 720 / 1500 (opposite directions)"),
    ("pipeline-loop00", "kitti00-loop 52 / 4501"),
    ("pipeline-apart", "kitti00-loop 88 / 850 (308 m apart: no overlap)"),
    ("pipeline-apart-network", "kitti00-loop 88 / 850, network labels"),
]
def pipeline_table(rows, title, command):
    """A table of the onboard pipeline per robot, one row per pair."""
    if not any(r for _, r in rows):
        return
    print(f"\n## {title}\n")
    print(f"{command}; instructions per robot A / B "
          "(the budget: 3e8 per robot; the search's budget: 40,000 nodes)\n")
    print("| pair | status A / B | e_t A / B | e_r A / B | voxels | map | prepare | locate | match | total | search nodes |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, r in rows:
        if not r:
            continue
        xs = r["robots"]
        st = " / ".join(x["status"] for x in xs)
        col = lambda k: " / ".join(f"{x.get(k, 0)/1e6:.0f} M" for x in xs)
        err = lambda k, unit: " / ".join(f"{x[k]:.3f}" if x["status"] == "Converged" else "-" for x in xs) + unit
        vox = " / ".join(f"{x['map_voxels']:,}" for x in xs)
        tot = " / ".join(f"{total(x)/1e6:.0f} M" for x in xs)
        nodes = " / ".join(f"{(x.get('global') or {}).get('evaluations', 0):,}" for x in xs)
        print(f"| {label} | {st} | {err('e_t', ' m')} | {err('e_r', ' deg')} | {vox} | {col('map_instructions')} | "
              f"{col('prepare_instructions')} | {col('locate_instructions')} | "
              f"{col('match_instructions')} | {tot} | {nodes} |")

pipeline_table([(label, load(f"{name}.json")) for name, label in PIPELINES],
               "The onboard pipeline per robot, no prior, emulated boards",
               "`cosem robots --data D --a A --b B --no-prior [--label-noise network] --json`")
STM32 = [
    ("stm32-kitti00", "kitti00 0:5 / 5:10"),
    ("stm32-kitti00-network", "kitti00 0:5 / 5:10, network labels"),
    ("stm32-loop08", "kitti08-loop 720 / 1500 (opposite directions)"),
    ("stm32-loop00", "kitti00-loop 52 / 4501"),
    ("stm32-apart", "kitti00-loop 88 / 850 (308 m apart: no overlap)"),
    ("stm32-apart-network", "kitti00-loop 88 / 850, network labels"),
]
pipeline_table([(label, load(f"{name}.json")) for name, label in STM32],
               "Both robots on STM32F405s (192 KiB, 3,008 voxels of 0.7 m), no prior",
               "`cosem robots --data D --a A --b B --no-prior [--label-noise network] "
               "--board-a stm32f405 --board-b stm32f405 --json`")

def placed(t):
    """Placed robots with their errors, unplaced ones, matches left out."""
    ok = [f"{r['index']} ({r['e_t']:.3f} m, {r['e_r']:.2f} deg)" for r in t["robots"]
          if r["index"] > 0 and r.get("placed") and r.get("group", 0) == 0 and "e_t" in r]
    other = [f"{r['index']}" + (f" (group {r['group']})" if r.get("group", 0) != 0 else " (unplaced)") for r in t["robots"]
             if r["index"] > 0 and not (r.get("placed") and r.get("group", 0) == 0)]
    reasons = Counter(m.get("reason", m.get("status")) for m in t.get("matches", []) if not m.get("accepted"))
    left = ", ".join(f"{n} {why}" for why, n in sorted(reasons.items())) or "none"
    return ", ".join(ok) or "none", ", ".join(other) or "none", left
TEAMS = [
    ("team-mixed", "kitti00 0:3, 3:6, 6:10 + kitti07 0:3"),
    ("team-injected", "the same, `--inject-false-match 0,1`"),
    ("team-groups", "kitti00 0:3, 3:6 + kitti08-loop 720, 1500"),
    ("team-street8", "synthetic street (`cosem synth --seed 21 --frames 24`) cut in eight"),
]
rows = [(label, load(f"{name}.json")) for name, label in TEAMS]
if any(t for _, t in rows):
    print("\n## Teams on the host, no prior, 0.2 m\n")
    print("`cosem team --robot PATH:START:END ... [--inject-false-match I,J] --json` (robot 0 is the frame every robot is placed in)\n")
    print("| team | placed in robot 0's frame (e_t, e_r) | not in robot 0's group | matches left out (why) |")
    print("|---|---|---|---|")
    for label, t in rows:
        if t:
            print("| " + label + " | " + " | ".join(placed(t)) + " |")
for name, title, command in [
    ("team-boards", "A team on emulated boards, kitti00 0:3, 3:6, 6:10, no prior, 0.5 m",
     "`cosem team --on-board --robot kitti00:0:3 --robot kitti00:3:6 --robot kitti00:6:10 --json`"),
    ("team-stm32", "A team of STM32F405s, kitti00 0:3, 3:6, 6:10, no prior, 1 m",
     "`cosem team --on-board --board stm32f405 --robot kitti00:0:3 --robot kitti00:3:6 --robot kitti00:6:10 --json`"),
]:
    t = load(f"{name}.json")
    if not t:
        continue
    print(f"\n## {title}\n")
    print(f"{command}\n")
    p, o, left = placed(t)
    print(f"Placed: {p}; not placed: {o}; matches left out: {left}; every board as the host: "
          f"{t['host_difference_m']:.1e} m apart at most; {t['wall_time_s']:.0f} s of wall time.\n")
    print("| board | map voxels | instructions: map / prepare / search / match / consistency and pose graph | peak stack |")
    print("|---|---|---|---|")
    for b in t["boards"]:
        m = lambda k: f"{b[k]/1e6:.0f} M"
        print(f"| {b['index']} | {b['map_voxels']:,} | {m('map_instructions')} / {m('prepare_instructions')} / "
              f"{m('locate_instructions')} / {m('match_instructions')} / {m('solve_instructions')} | {b['peak_stack_bytes']:,} B |")
PY
echo "docs/results.md written"
