#!/usr/bin/env bash
# Installs the Debian packages the project needs (cross compiler, cmocka, QEMU,
# OpenOCD, Chromium for the report check, LinuxCNC for the external-offset test,
# mosquitto and PostgreSQL for the fleet tests, started by the tests themselves,
# tmux for the monitor's terminal tests).
# Skips apt when everything is present, uses sudo when not root. Always
# --no-install-recommends (see docs/platform notes).
set -euo pipefail
pkgs=(make gcc python3-venv gcc-arm-none-eabi libnewlib-arm-none-eabi libcmocka-dev
      qemu-system-arm openocd chromium linuxcnc-uspace mosquitto mosquitto-clients
      postgresql openssl tmux)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "system packages: all present"
  exit 0
fi
echo "system packages: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
