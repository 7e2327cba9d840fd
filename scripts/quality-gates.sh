#!/usr/bin/env bash
# The quality gates at the defaults on the nine shared meshes: convert each (release build), then print one
# Markdown row per mesh (wall seconds and peak RSS of the whole process, exit status, status, every gate's
# value, chains built, the far tail and why the net was refined locally), then the same for the two shared meshes
# the chain does not deliver yet (sword, beetle). BENCHMARKS.md keeps the latest table.
#
#   cargo build --release && bash scripts/quality-gates.sh [OUT_DIR]    (SCANSTATION_BIN: another binary)
#
# Uses ../shared/data (override: SCANSTATION_SHARED_DATA). About 8 minutes on 2 cores (11 with sword and beetle).
set -uo pipefail
cd "$(dirname "$0")/.."
data=$(realpath "${SCANSTATION_SHARED_DATA:-../shared/data}")
out=$(realpath -m "${1:-target/quality-gates}")
mkdir -p "$out"
bin=${SCANSTATION_BIN:-target/release/scanstation}
echo "| mesh | wall s | peak RSS MiB | exit | status | crossings | folds | volume % | RMS % (bound 0.05) | max distance % (bound 2.0; goal 0.2) | scan vertices beyond 0.2 % | refined for | chains | net raises (vertices, net RMS %) | repair / remesh / surface / brep / step s |"
echo "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---|---|"
for f in meshes/spot.ply meshes/armadillo_50k.ply meshes/igea.ply meshes/fandisk.ply bunny/reconstruction/bun_zipper.ply \
         large/dragon_vrip_draco.ply.gz meshes/scorpion.ply meshes/skull.ply meshes/falconstatue_boundary.ply \
         meshes/sword.ply meshes/beetle.ply; do
  m=$(basename "$f"); m=${m%%.*}
  /usr/bin/time -f "%e %M" -o "$out/$m.time" "$bin" convert "$data/$f" -o "$out/$m.step" --report "$out/$m.json" \
    >"$out/$m.txt" 2>"$out/$m.err"
  code=$?
  python3 - "$out" "$m" "$code" <<'PY'
import json, sys
out, m, code = sys.argv[1:4]
wall, kb = open(f"{out}/{m}.time").read().split()[-2:]
try:
    d = json.load(open(f"{out}/{m}.json"))
except (OSError, ValueError):
    err = [l for l in open(f"{out}/{m}.err") if "error:" in l]
    code_name = err[-1].split("[")[1].split("]")[0] if err else "?"
    print(f"| {m} | {float(wall):.1f} | {int(kb)/1024:.0f} | {code} | `{code_name}` | | | | | | | | | | |")
    sys.exit()
g = {x["name"]: x["value"] for x in d["gates"]}
def raises(d):
    r = [x for a in d["attempts"] for x in a.get("raises", [])]
    return "; ".join(f"{x['from_vertices']} → {x['to_vertices']} ({x['from_rms_pct']:.3f} → {x['to_rms_pct']:.3f}, "
                     f"{'kept' if x['kept'] else 'not kept'})" for x in r) or "none"
def stages(d):
    s = {x["stage"]: x["seconds"] for x in d["stages"]}
    return " / ".join(f"{s.get(k, 0):.1f}" for k in ["repair", "remesh", "surface", "brep", "step"])
brep = [s for s in d["stages"] if s["stage"] == "brep"][-1]["distance"]["reference_to_test"]["max"]["pct_of_diagonal"]
t = d.get("far_tail") or {"vertices_beyond_goal": "–"}
g.setdefault("max-distance", brep)  # a binary before the far-tail gate: the brep stage's scan → solid max
why = d["attempts"][-1]["local"].get("trigger") or "–"
print(f"| {m} | {float(wall):.1f} | {int(kb)/1024:.0f} | {code} | {d['status']} | {g['crossings']:.0f} | {g['folds']:.0f} "
      f"| {g['volume']:.3f} | {g['rms']:.4f} | {g['max-distance']:.3f} | {t['vertices_beyond_goal']} | {why} "
      f"| {len(d['attempts'])} | {raises(d)} | {stages(d)} |")
PY
done
