#!/usr/bin/env bash
# Real SocketCAN without a CAN-capable kernel: boot Debian's user-mode Linux (a Linux 6.1 kernel run as an
# ordinary process) with this machine's filesystem as its root (hostfs), load can, can-raw, can-dev, vcan and
# sch_tbf, create vcan0 and vcan1 (vcan1 behind a 1 kB/s token bucket with room for four frames, so a burst
# gives ENOBUFS), run a command inside, power off, and exit with the command's status.
#
#   bash scripts/uml-vcan.sh            # build and run tests/vcan.rs inside (what .ci/run does)
#   bash scripts/uml-vcan.sh CMD ARGS…  # run CMD inside instead (absolute paths: the root is this machine's /)
#
# The kernel and kmod's insmod are fetched once with `apt-get download` into target/uml (override:
# SCANSTATION_UML_DIR) and extracted there; nothing is installed. Fails loudly, with the reason, when the
# packages cannot be fetched, the kernel does not boot, or the command does not report a status.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
dir=${SCANSTATION_UML_DIR:-$root/target/uml}
limit=${SCANSTATION_UML_TIMEOUT:-900}
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)

fail() { echo "uml-vcan: $*" >&2; exit 1; }

# 1. The kernel (user-mode-linux: linux.uml and its modules) and insmod (kmod), extracted, not installed.
fetch() { # package, file that shows it is there
    local pkg=$1 have=$2
    [ -e "$dir/$have" ] && return 0
    ( cd "$dir" && rm -f "${pkg}"_*.deb
      apt-get download "$pkg" >/dev/null 2>&1 || { apt-get update >/dev/null 2>&1 && apt-get download "$pkg"; } ) \
        || fail "cannot fetch Debian's $pkg with apt-get download (needs the Debian package registry)"
    dpkg -x "$dir/${pkg}"_*.deb "$dir/$pkg" || fail "cannot extract $pkg"
    [ -e "$dir/$have" ] || fail "$pkg has no $have"
}
fetch user-mode-linux user-mode-linux/usr/bin/linux.uml
fetch kmod kmod/bin/kmod
ln -sf "$dir/kmod/bin/kmod" "$dir/insmod"
modules=$(ls -d "$dir"/user-mode-linux/usr/lib/uml/modules/*/kernel | head -1)
[ -d "$modules" ] || fail "no modules in the user-mode-linux package"

# 2. What to run inside: by default the vcan test binary, built here first.
if [ $# -eq 0 ]; then
    out=$(cd "$root" && cargo test --locked --features vcan-tests --test vcan --no-run 2>&1) \
        || { echo "$out" >&2; fail "building tests/vcan.rs failed"; }
    bin=$(echo "$out" | sed -n 's/.*Executable tests\/vcan.rs (\(.*\))/\1/p' | tail -1)
    [ -n "$bin" ] || { echo "$out" >&2; fail "cannot find the vcan test binary in cargo's output"; }
    set -- "$root/$bin" --test-threads 1 --nocapture
fi

# 3. The init script: modules, interfaces, the command, its status, power off.
status=$dir/status
log=$dir/output.log
rm -f "$status" "$log"
{
    echo '#!/bin/sh'
    echo 'export PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root'
    echo 'mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t tmpfs tmpfs /dev/shm 2>/dev/null'
    echo "cd '$root'"
    echo "for m in net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko net/sched/sch_tbf.ko; do"
    echo "  '$dir/insmod' '$modules'/\$m || { echo \"insmod \$m failed\"; echo 97 > '$status'; halt -f; }"
    echo 'done'
    echo 'ip link add dev vcan0 type vcan && ip link set up vcan0 &&'
    echo 'ip link add dev vcan1 type vcan && ip link set up vcan1 &&'
    echo 'tc qdisc add dev vcan1 root tbf rate 8kbit burst 32 limit 64 || { echo 98 > '"'$status'"'; halt -f; }'
    printf '%q ' "$@"
    echo "> '$log' 2>&1"
    echo "echo \$? > '$status'"
    echo 'halt -f'
} > "$dir/init.sh"
chmod +x "$dir/init.sh"

# 4. Boot (the kernel's console goes to a log; the command's output is printed after).
echo "uml-vcan: booting user-mode Linux ($(basename "$(dirname "$modules")")) to run: $*"
timeout "$limit" "$dir/user-mode-linux/usr/bin/linux.uml" mem=1024M root=/dev/root rootfstype=hostfs rootflags=/ rw \
    init="$dir/init.sh" con=null con0=null,fd:1 > "$dir/console.log" 2>&1 \
    || fail "user-mode Linux failed or ran past ${limit}s (console: $dir/console.log): $(tail -3 "$dir/console.log")"
[ -f "$log" ] && cat "$log"
[ -f "$status" ] || fail "the command reported no status (console: $dir/console.log): $(tail -5 "$dir/console.log")"
code=$(cat "$status")
case $code in
    97) fail "a CAN module did not load inside user-mode Linux (console: $dir/console.log)";;
    98) fail "vcan0/vcan1 could not be created inside user-mode Linux";;
esac
echo "uml-vcan: the command exited with $code"
exit "$code"
