#!/usr/bin/env bash
# Gives this network namespace a multicast route if LCM's loopback multicast delivers nothing,
# so the two-process LCM tests (tests/test_sim_driver_bus.py) run instead of failing.
# A fresh namespace (a container, `unshare -n`) has no route for 224.0.0.0/4: LCM then only
# warns and delivers nothing. Needs root (CI is); run from the repository with .venv set up.
set -uo pipefail
cd "$(dirname "$0")/.."

loopback() {
  .venv/bin/python -c "import sys; from doorlab.hardware.protocol import lcm_delivers; \
sys.exit(0 if lcm_delivers('udpm://239.255.76.67:$((20000 + RANDOM % 40000))?ttl=0', timeout=2.0) else 1)"
}

if ! command -v ip >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq iproute2 >/dev/null) \
    || echo "warning: could not install iproute2 (the ip command)"
fi
if command -v ip >/dev/null 2>&1 && ip route get 239.255.76.67 >/dev/null 2>&1 && loopback; then
  echo "LCM loopback multicast: ok"
  exit 0
fi
echo "LCM loopback multicast delivers nothing: adding a multicast route on lo"
if [ "$(id -u)" != 0 ]; then
  echo "warning: not root; as root: ip link set lo up; ip route add 224.0.0.0/4 dev lo"
  exit 0
fi
ip link set lo up
ip route add 224.0.0.0/4 dev lo 2>/dev/null || ip route replace 224.0.0.0/4 dev lo
if loopback; then
  echo "LCM loopback multicast: ok (route 224.0.0.0/4 dev lo added)"
else
  echo "warning: LCM loopback multicast still delivers nothing; the LCM tests will fail"
fi
