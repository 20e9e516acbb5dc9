"""Field faults a simulated robot can be put through, and their cure.

    cut(name)                  the robot's SSH link drops (packets to its sshd vanish, as on a Wi-Fi
                               dropout); the robot itself keeps running. `seconds=` heals it by itself.
    isolate(name, "registry")  the robot cannot reach the registry; its SSH link still works
    heal(name)                 both undone
    busy(name, True|False)     the demo driver's /robot_mode says BUSY or IDLE
    reboot(name)               `docker restart` of the robot: its engine, sshd and containers restart

Rules live in one iptables chain per direction inside the robot's own network namespace, so
`heal` is one flush and a reboot (a new namespace) heals too, as a real reboot would. The
scripts are fixed text run with `docker exec`; values reach them as positional arguments.
"""
from __future__ import annotations

from rosdeploy.errors import SimError
from rosdeploy.sim.model import REGISTRY_ROBOT, container_of, robot_for, robot_index
from rosdeploy.sim.proc import docker
from rosdeploy.sim.robots import robot_exec, wait_ready

_CHAINS = """
ipt() { iptables -w "$@"; }
for pair in INPUT:ROSDEPLOY-SIM-IN OUTPUT:ROSDEPLOY-SIM-OUT; do
    parent=${pair%%:*} chain=${pair#*:}
    ipt -N "$chain" 2>/dev/null || true
    ipt -C "$parent" -j "$chain" 2>/dev/null || ipt -I "$parent" 1 -j "$chain"
done
"""

# DROP, not REJECT: a Wi-Fi dropout answers nothing; the controller must notice by itself.
_CUT = _CHAINS + """
ipt -C ROSDEPLOY-SIM-IN -p tcp --dport 22 -j DROP 2>/dev/null || ipt -A ROSDEPLOY-SIM-IN -p tcp --dport 22 -j DROP
if [ "$1" != 0 ]; then
    # Heals by itself after $1 seconds (a short blip), detached from this docker exec.
    setsid sh -c 'sleep "$1"; iptables -w -D ROSDEPLOY-SIM-IN -p tcp --dport 22 -j DROP' sh "$1" \
        </dev/null >/dev/null 2>&1 &
    echo $! >/run/rosdeploy-sim-heal.pid
fi
"""

# The registry is a host port seen through host-gateway: refuse it at once (no route).
_ISOLATE_REGISTRY = _CHAINS + """
addr=$(getent hosts "$1" | awk '{print $1; exit}')
[ -n "$addr" ] || { echo "cannot resolve $1 inside the robot" >&2; exit 1; }
rule="-p tcp -d $addr --dport $2 -j REJECT --reject-with icmp-host-unreachable"
# shellcheck disable=SC2086  # $rule is our own fixed words plus an address getent printed
ipt -C ROSDEPLOY-SIM-OUT $rule 2>/dev/null || ipt -A ROSDEPLOY-SIM-OUT $rule
"""

_HEAL = _CHAINS + """
# A pending timed heal of an earlier `cut --for` must not fire into a later cut.
if [ -f /run/rosdeploy-sim-heal.pid ]; then
    kill -- "-$(cat /run/rosdeploy-sim-heal.pid)" 2>/dev/null || true
    rm -f /run/rosdeploy-sim-heal.pid
fi
ipt -F ROSDEPLOY-SIM-IN
ipt -F ROSDEPLOY-SIM-OUT
"""

_RULES = """
for chain in ROSDEPLOY-SIM-IN ROSDEPLOY-SIM-OUT; do iptables -w -S "$chain" 2>/dev/null | grep -- '^-A' || true; done
"""

# The demo driver reads its mode from this file in its own container (default IDLE).
MODE_FILE = "/tmp/robot_mode"
_MODE = """
ids=$(docker ps -q --filter label=com.docker.compose.service="$1")
[ -n "$ids" ] || { echo "no running $1 container on this robot" >&2; exit 1; }
for id in $ids; do docker exec "$id" sh -c 'printf "%s\\n" "$1" >"$2"' sh "$2" "$3"; done
"""


def _sh(robot_name: str, script: str, *args: str) -> str:
    result = robot_exec(robot_name, ["sh", "-euc", script, "sh", *args], timeout=60)
    if result.returncode != 0:
        raise SimError(f"{robot_name}: {result.stderr.strip() or 'fault script failed'}")
    return result.stdout


def cut(robot_name: str, seconds: float = 0) -> None:
    """Drop every packet to the robot's sshd (new and open connections) until heal()."""
    _sh(robot_name, _CUT, f"{max(0.0, seconds):g}")


def isolate(robot_name: str, what: str = "registry") -> None:
    if what != "registry":
        raise SimError(f"sim isolate: can isolate a robot from 'registry', not {what!r}")
    host, port = REGISTRY_ROBOT.rsplit(":", 1)
    _sh(robot_name, _ISOLATE_REGISTRY, host, port)


def heal(robot_name: str) -> None:
    _sh(robot_name, _HEAL)


def faults(robot_name: str) -> list[str]:
    """The fault rules in force on a robot, as iptables prints them (empty when healthy)."""
    return [line for line in _sh(robot_name, _RULES).splitlines() if line]


def busy(robot_name: str, on: bool, service: str = "driver") -> None:
    """Set the demo driver's /robot_mode to BUSY (on) or IDLE; the driver must be running."""
    _sh(robot_name, _MODE, service, "BUSY" if on else "IDLE", MODE_FILE)


def reboot(robot_name: str) -> None:
    """Restart the robot's container (a power cycle) and wait until it takes SSH again."""
    docker("restart", "-t", "5", container_of(robot_name), what=f"restarting {robot_name}", timeout=120)
    wait_ready([robot_for(robot_index(robot_name))])
