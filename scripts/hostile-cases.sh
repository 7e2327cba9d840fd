#!/usr/bin/env bash
# The field failures of the hostile-input issue, at their original sizes, through the release CLI with
# --memory-budget 1G under a 4 GB address-space limit: one Markdown row per case (exit, code, wall s, peak RSS).
#
#   cargo build --release && bash scripts/hostile-cases.sh [DIR]
#
# Writes about 8 MB of gzip and sparse files into DIR (default target/hostile-cases). Needs python3 and
# GNU time (/usr/bin/time, Debian package `time`).
set -uo pipefail
cd "$(dirname "$0")/.."
bin=$(realpath target/release/scanstation)
dir=$(realpath -m "${1:-target/hostile-cases}")
mkdir -p "$dir" && cd "$dir"
python3 - <<'PY'
import zlib
def gz(path, unit, total, member=1 << 20):
    block = unit * (member // len(unit))
    c = zlib.compressobj(9, zlib.DEFLATED, 31); one = c.compress(block) + c.flush()
    with open(path, "wb") as f:
        for _ in range(total // len(block)): f.write(one)
gz("bomb.ply.gz", b"\0", 2_300_000_000)
gz("members.xyz.gz", b"\0", 10 * 256_000_000)
gz("records.xyz.gz", b"0 0 0\n", 2_300_000_000)
def sparse(path, prefix, n):
    with open(path, "wb") as f: f.write(prefix); f.truncate(n)
sparse("comment.ply", b"ply\nformat ascii 1.0\ncomment ", 2_300_000_000)
sparse("line.obj", b"v ", 2_300_000_000)
sparse("zeros.xyz", b"", 2_300_000_000)
PY
spec=$(realpath "$OLDPWD/config/fea/cantilever-rod.toml"); rod=$(realpath "$OLDPWD/examples/rod.ply")
root='plane = { point = [0.001, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }'
sed 's/^cell_size = 1.0 /cell_size = 0.05/' "$spec" > fine.toml
sed "0,/$(printf '%s' "$root" | sed 's/[][]/\\&/g')/s//sphere = { center = [0.0, 0.0, 0.0], radius = 1e308 }/" "$spec" > sphere.toml
sed "0,/$(printf '%s' "$root" | sed 's/[][]/\\&/g')/s//plane = { point = [-10.0, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }/" "$spec" > everything.toml
{ cat "$spec"; for i in $(seq 2000); do printf '\n[[loads]]\nplane = { point = [199.999, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }\nforce = [0.0, 0.01, 0.0]\n'; done; } > loads.toml
{ cat "$spec"; for i in $(seq 5000); do printf '\n[[supports]]\n%s\n' "$root"; done; } > supports.toml
echo "| case | command | exit | code | wall s | peak RSS MiB |"
echo "|---|---|---:|---|---:|---:|"
row() { # name, args...
  local name=$1; shift
  /usr/bin/time -f "%e %M" -o t.txt bash -c 'ulimit -v 4000000; exec "$@"' _ "$bin" --memory-budget 1G --json "$@" > o.json 2>/dev/null
  local code=$?
  read -r wall kb < <(tail -1 t.txt)
  local err; err=$(python3 -c 'import json,sys; print(json.load(open("o.json")).get("error_code","-"))' 2>/dev/null || echo "?")
  echo "| $name | $1 | $code | \`$err\` | $wall | $((kb / 1024)) |"
}
for f in bomb.ply.gz members.xyz.gz records.xyz.gz comment.ply line.obj zeros.xyz; do
  row "$f" inspect "$f"; row "$f" repair "$f" -o out.ply
done
for s in fine sphere everything loads supports; do row "spec $s" fea "$rod" --spec "$s.toml" -o fea-out; done
row "spec /dev/urandom" fea "$rod" --spec /dev/urandom -o fea-out
