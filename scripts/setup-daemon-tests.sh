#!/usr/bin/env bash
# Tools tests/daemon.rs drives the daemon with: dbus-daemon, busctl and systemd-analyze, gdbus, setpriv; and the
# headless Chromium the report pages are opened in (tests/report.rs, tests/daemon.rs, scripts/browser-check.py).
# Installs the Debian packages that are missing (needs root or sudo); does nothing when all are present.
# Also the one-node Slurm cluster's packages (munge, slurmctld, slurmd, slurm-client) tests/cluster.rs runs on.
set -euo pipefail
bash "$(dirname "$0")/slurm-cluster.sh" install
declare -A pkg=([dbus-daemon]=dbus-daemon [busctl]=systemd [systemd-analyze]=systemd [gdbus]=libglib2.0-bin [setpriv]=util-linux [chromium]=chromium)
missing=()
for tool in "${!pkg[@]}"; do
  command -v "$tool" >/dev/null 2>&1 || missing+=("${pkg[$tool]}")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "daemon test tools: all present"
  exit 0
fi
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
echo "installing: ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq $(printf '%s\n' "${missing[@]}" | sort -u)
