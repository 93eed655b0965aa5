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
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
