#!/usr/bin/env bash
# Writes every output the chain makes on the shared meshes and examples/ into OUT_DIR, with the reports' timings
# and peak memories removed, so a refactor can be checked byte for byte:
#
#   bash scripts/fingerprint-outputs.sh /tmp/before-bin/scanstation /tmp/before      # at the old commit
#   bash scripts/fingerprint-outputs.sh target/release/scanstation /tmp/after          # at the new one
#   diff -r /tmp/before /tmp/after && echo identical                                   # (cmp on every file)
#
# What it runs (defaults unless named): repair of the bunny and the dragon; remesh --vertices 10000 of the
# closed shared meshes and the repaired two; convert of every shared mesh and of examples/spot.ply at 5000
# (the README's main job) with its quads and report; fea of examples/rod.ply and of spot's solid. About 5 minutes
# in release on 2 cores. Uses ../shared/data (override: SCANSTATION_SHARED_DATA).
set -euo pipefail
bin=$(realpath "$1")
out=$(realpath -m "$2")
data=$(realpath "${SCANSTATION_SHARED_DATA:-$(dirname "$0")/../../shared/data}")
cd "$(dirname "$0")/.."
mkdir -p "$out"
m=$data/meshes

# Reports without their timings, peak memories and the paths of this run.
strip() {
  python3 - "$1" "$out" "$data" <<'PY'
import json, sys
path, out, data = sys.argv[1:4]
def clean(x):
    if isinstance(x, dict):
        return {k: clean(v) for k, v in x.items()
                if not ("seconds" in k or k.startswith("peak_") or k.endswith("_mib") or k in ("hostname",))}
    if isinstance(x, list):
        return [clean(v) for v in x]
    if isinstance(x, str):
        return x.replace(out, "OUT").replace(data, "DATA")
    return x
with open(path) as f:
    d = json.load(f)
with open(path, "w") as f:
    json.dump(clean(d), f, indent=1, sort_keys=True)
PY
}

run() { # name, then the command's arguments; its --json report becomes NAME.json
  local name=$1; shift
  # A failed run (a gate refusing the solid) still writes its report: its exit status goes beside it, so the
  # report stays JSON and is stripped like the others.
  "$bin" "$@" --json > "$out/$name.json" || echo "exit $? for $name" > "$out/$name.exit"
  strip "$out/$name.json" 2>/dev/null || true
}

run bunny.repair repair "$data/bunny/reconstruction/bun_zipper.ply" -o "$out/bunny.repaired.ply"
run dragon.repair repair "$data/large/dragon_vrip_draco.ply.gz" -o "$out/dragon.repaired.ply"
for name in igea fandisk armadillo_50k spot; do
  run "$name.remesh" remesh "$m/$name.ply" -o "$out/$name.remesh.obj" --vertices 10000
done
for name in bunny dragon; do
  run "$name.remesh" remesh "$out/$name.repaired.ply" -o "$out/$name.remesh.obj" --vertices 10000
done
for name in igea fandisk armadillo_50k spot; do
  run "$name.convert" convert "$m/$name.ply" -o "$out/$name.step" --quads "$out/$name.quads.obj" --report "$out/$name.report.json"
done
run bunny.convert convert "$data/bunny/reconstruction/bun_zipper.ply" -o "$out/bunny.step" --quads "$out/bunny.quads.obj" \
  --report "$out/bunny.report.json"
run dragon.convert convert "$data/large/dragon_vrip_draco.ply.gz" -o "$out/dragon.step" --quads "$out/dragon.quads.obj" \
  --report "$out/dragon.report.json"
run example-spot.convert convert examples/spot.ply -o "$out/example-spot.step" --vertices 5000 \
  --quads "$out/example-spot.quads.obj" --report "$out/example-spot.report.json"
run rod.fea fea examples/rod.ply --spec config/fea/cantilever-rod.toml -o "$out/rod-fea"
run spot.fea fea "$out/example-spot.step" --spec config/fea/spot-standing.toml -o "$out/spot-fea"
for r in "$out"/*.report.json "$out"/*-fea/result.json; do
  [ -f "$r" ] && strip "$r"
done
echo "outputs in $out:"
ls -la "$out" | tail -n +2 | wc -l
