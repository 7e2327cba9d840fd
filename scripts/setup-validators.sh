#!/usr/bin/env bash
# Install what the conformance suite needs: a Python virtualenv (.venv-validators/) with the pinned packages of
# ../shared/validators that our suites call (point-cloud-utils, trimesh, numpy, scipy; pyinstantmeshes, the peer remesher;
# cadquery-ocp (OpenCASCADE) and gmsh for the STEP checks; meshio for the FEA's VTU files). Idempotent.
# Usage: bash scripts/setup-validators.sh [--peers]  (SCANSTATION_VALIDATORS overrides ../shared/validators)
# --peers also installs Open3D and PyMeshLab (the reconstruction peers of `cargo bench --bench reconstruct` and
# scripts/reconstruct-peers.sh) and the Debian package Open3D needs (libusb-1.0-0).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
kit="${SCANSTATION_VALIDATORS:-$root/../shared/validators}"
venv="$root/.venv-validators"
if [ ! -f "$kit/requirements.txt" ]; then
  echo "setup-validators: $kit/requirements.txt not found (set SCANSTATION_VALIDATORS to the validators kit)" >&2
  exit 1
fi
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
# Only the packages our suites use, at the kit's pinned versions.
pins=$(grep -E '^(numpy|scipy|trimesh|rtree|point-cloud-utils|pyinstantmeshes|cadquery-ocp|gmsh)==' "$kit/requirements.txt" | sed 's/[[:space:]]*#.*//')
# shellcheck disable=SC2086
"$venv/bin/pip" install -q --disable-pip-version-check $pins
# meshio reads our FEA result files (VTU) the way ParaView users' scripts do; not in the kit's list.
"$venv/bin/pip" install -q --disable-pip-version-check meshio==5.3.5
"$venv/bin/python" -c "import point_cloud_utils, trimesh, numpy, scipy, pyinstantmeshes, OCP, gmsh, meshio; print('validators venv ok:', '$venv')"
if [ "${1:-}" = "--peers" ]; then
  if ! ldconfig -p | grep -q libusb-1.0.so.0; then
    apt-get install -y -q libusb-1.0-0 >/dev/null
  fi
  pins=$(grep -E '^(open3d|pymeshlab)==' "$kit/requirements.txt" | sed 's/[[:space:]]*#.*//')
  # shellcheck disable=SC2086
  "$venv/bin/pip" install -q --disable-pip-version-check $pins
  "$venv/bin/python" -c "import open3d, pymeshlab; print('open3d', open3d.__version__, 'and pymeshlab')"
fi
