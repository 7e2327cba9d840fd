#!/usr/bin/env bash
# Reconstruction against Open3D's screened Poisson in the same run: the vertices of armadillo and igea as
# clouds without normals (each tool estimates and orients them), each result measured against the source mesh
# by `scanstation compare` (symmetric RMS, % of the diagonal). One Markdown row per run: wall s, peak RSS.
#
#   cargo build --release && bash scripts/setup-validators.sh --peers && bash scripts/reconstruct-peers.sh [OUT_DIR]
#
# Uses ../shared/data (override: SCANSTATION_SHARED_DATA) and ../shared/validators/poisson_peer.py.
set -uo pipefail
cd "$(dirname "$0")/.."
data=$(realpath "${SCANSTATION_SHARED_DATA:-../shared/data}")
val=$(realpath ../shared/validators)
out=$(realpath -m "${1:-target/reconstruct-peers}")
mkdir -p "$out"
bin=$(realpath target/release/scanstation)
py="$PWD/.venv-validators/bin/python"  # not realpath: that would leave the venv for the system python
echo "| cloud | tool | setting | wall s | peak RSS MiB | RMS to the source mesh, % diag |"
echo "|---|---|---|---:|---:|---:|"
row() { # cloud tool setting result time
  local rms; rms=$("$bin" compare "$4" "$data/meshes/$1.ply" 2>/dev/null | awk '/^symmetric +rms/ {print $4}')
  read -r wall kb < <(tail -1 "$5")
  echo "| $1 | $2 | $3 | $wall | $((kb / 1024)) | ${rms:-failed} |"
}
for m in armadillo_50k igea; do
  for res in 0 256; do
    set_name=$([ "$res" = 0 ] && echo "default (0.6·√n)" || echo "--resolution $res")
    extra=$([ "$res" = 0 ] && echo "" || echo "--resolution $res")
    /usr/bin/time -f "%e %M" -o "$out/t" "$bin" reconstruct "$data/meshes/$m.ply" -o "$out/$m-ours-$res.ply" $extra >/dev/null 2>&1
    row "$m" scanstation "$set_name" "$out/$m-ours-$res.ply" "$out/t"
  done
  for depth in 8 9; do
    (cd "$val" && /usr/bin/time -f "%e %M" -o "$out/t" "$py" poisson_peer.py "$data/meshes/$m.ply" \
      --out "$out/$m-open3d-$depth.ply" --depth "$depth" --force-estimate-normals >"$out/$m-open3d-$depth.json" 2>/dev/null)
    row "$m" "Open3D 0.20" "depth $depth" "$out/$m-open3d-$depth.ply" "$out/t"
  done
done
