#!/usr/bin/env bash
# Install the Debian packages named on the command line when they are missing.
# As root we install them with apt-get; otherwise we say exactly what to run and stop.
set -euo pipefail
missing=()
for pkg in "$@"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
[ ${#missing[@]} -eq 0 ] && exit 0
if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: cannot install ${missing[*]}: this is not a Debian/Ubuntu system; install their equivalents and rerun" >&2
    exit 1
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "setup: missing system packages: ${missing[*]}; run 'sudo apt-get install -y ${missing[*]}' and rerun make" >&2
    exit 1
fi
echo "setup: installing system packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
# Another apt/dpkg process (unattended-upgrades on a fresh machine) may hold the locks: wait for it
# (up to APT_LOCK_TIMEOUT seconds, default 600) instead of failing.
lock_timeout="${APT_LOCK_TIMEOUT:-600}"
apt_opts=(-o "DPkg::Lock::Timeout=${lock_timeout}")
wait_for_apt_locks() {
    command -v fuser >/dev/null 2>&1 || return 0
    local waited=0
    while fuser /var/lib/dpkg/lock-frontend /var/lib/dpkg/lock /var/lib/apt/lists/lock >/dev/null 2>&1; do
        [ "$waited" -eq 0 ] && echo "setup: waiting for another apt/dpkg process to finish (up to ${lock_timeout} s)"
        if [ "$waited" -ge "$lock_timeout" ]; then
            echo "setup: apt is still locked by another process after ${lock_timeout} s; rerun make when it is done" >&2
            exit 1
        fi
        sleep 5
        waited=$((waited + 5))
    done
}
wait_for_apt_locks
apt-get "${apt_opts[@]}" update -qq
wait_for_apt_locks
apt-get "${apt_opts[@]}" install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
