#!/usr/bin/env bash
# Creates the virtual CAN interface the SocketCAN tests and `climbsim serve --can` use:
#   sudo hil/vcan-setup.sh [IFACE]     (default vcan0)
# then `CLIMBSIM_VCAN=vcan0 ./scripts/test.sh`. Needs a kernel with the vcan module (most distro
# kernels; not most containers or CI VMs). Running it again is harmless.
set -euo pipefail
iface="${1:-vcan0}"
if [[ $EUID -ne 0 ]]; then
    echo "vcan-setup: run as root (sudo $0 $iface)" >&2
    exit 1
fi
modprobe vcan
if ! ip link show dev "$iface" >/dev/null 2>&1; then
    ip link add dev "$iface" type vcan
fi
ip link set up "$iface"
ip -details link show dev "$iface"
