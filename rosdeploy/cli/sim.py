"""`rosdeploy sim up|down|status`: a simulated fleet on this machine (see rosdeploy.sim)."""
from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

from rosdeploy.output import Output

if TYPE_CHECKING:
    from rosdeploy import sim

# `rosdeploy.sim` is imported by the handlers: every command builds the whole parser, and
# the others (an emergency rollback among them) need none of it.


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("sim", help="a simulated robot fleet on this machine (Docker-in-Docker robots)",
                            description="Robots are containers with sshd and their own Docker engine; "
                                        "state lives in $ROSDEPLOY_SIM_HOME (default ~/.rosdeploy/sim).")
    actions = parser.add_subparsers(dest="sim_command", metavar="ACTION", required=True)

    up = actions.add_parser("up", help="start the robots, the registry, and build the demo images if needed")
    up.add_argument("--robots", type=int, default=3, metavar="N", help="number of robots (default 3)")
    up.set_defaults(func=cmd_up)

    down = actions.add_parser("down", help="remove the robots and the registry the simulator started")
    down.add_argument("--purge", action="store_true",
                      help="also remove the simulator's images, registry data and state dir")
    down.set_defaults(func=cmd_down)

    status = actions.add_parser("status", help="list the robots, their addresses and state")
    # Its own dest: a subparser default would otherwise reset the global --json.
    status.add_argument("--json", dest="status_json", action="store_true",
                        help="print one JSON document on stdout")
    status.set_defaults(func=cmd_status)
    _register_faults(actions)


def _register_faults(actions: argparse._SubParsersAction) -> None:
    """Field faults to rehearse on: a cut link, a robot without its registry, a busy robot, a reboot."""
    cut = actions.add_parser("cut", help="drop a robot's SSH link (the robot keeps running) until `sim heal`",
                             description="Every packet to the robot's sshd is dropped, on open connections "
                                         "too, as when a robot roams out of Wi-Fi range.")
    cut.add_argument("robot", metavar="ROBOT")
    cut.add_argument("--for", dest="seconds", type=_seconds, default=0.0, metavar="DURATION",
                     help="heal by itself after this long (e.g. 2s: a Wi-Fi blip)")
    cut.set_defaults(func=cmd_fault, fault="cut")
    isolate = actions.add_parser("isolate", help="cut a robot off from the registry; its SSH link still works")
    isolate.add_argument("robot", metavar="ROBOT")
    isolate.add_argument("--from", dest="target", choices=["registry"], default="registry")
    isolate.set_defaults(func=cmd_fault, fault="isolate")
    heal = actions.add_parser("heal", help="undo `sim cut` and `sim isolate` on a robot")
    heal.add_argument("robot", metavar="ROBOT")
    heal.set_defaults(func=cmd_fault, fault="heal")
    busy = actions.add_parser("busy", help="set the demo driver's /robot_mode to BUSY (on) or IDLE (off)")
    busy.add_argument("robot", metavar="ROBOT")
    busy.add_argument("state", choices=["on", "off"])
    busy.set_defaults(func=cmd_fault, fault="busy")
    reboot = actions.add_parser("reboot", help="restart a robot (its engine, sshd and containers) and wait for it")
    reboot.add_argument("robot", metavar="ROBOT")
    reboot.set_defaults(func=cmd_fault, fault="reboot")


def _seconds(text: str) -> float:
    from rosdeploy.fleet import parse_duration
    try:
        return parse_duration(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration (e.g. 2s, 500ms, 1m)") from None


def cmd_fault(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import sim
    sim.load()       # a clear "run `rosdeploy sim up`" when there is no fleet
    name = args.robot
    if args.fault == "cut":
        sim.cut(name, args.seconds)
        out.line(f"{name}: SSH link cut" + (f" for {args.seconds:g} s" if args.seconds else "; `rosdeploy sim heal "
                                                                                                f"{name}` restores it"))
    elif args.fault == "isolate":
        sim.isolate(name, args.target)
        out.line(f"{name}: cut off from the {args.target}; SSH still works")
    elif args.fault == "heal":
        sim.heal(name)
        out.line(f"{name}: link and registry restored")
    elif args.fault == "busy":
        sim.busy(name, args.state == "on")
        out.line(f"{name}: /robot_mode {'BUSY' if args.state == 'on' else 'IDLE'}")
    else:
        sim.reboot(name)
        out.line(f"{name}: restarted and reachable")
    return 0


def _progress(out: Output):
    started = time.monotonic()
    return lambda message: out.line(f"[{time.monotonic() - started:5.1f}s] {message}")


def cmd_up(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import sim
    started = time.monotonic()
    fleet = sim.up(robots=args.robots, progress=_progress(out))
    out.line(f"{len(fleet.robots)} robots up in {time.monotonic() - started:.1f} s")
    out.table(["ROBOT", "SSH", "ROS_DOMAIN_ID"],
              [[r.name, f"robot@{r.host}:{r.ssh_port}", r.ros_domain_id] for r in fleet.robots])
    out.line(f"inventory:   {fleet.inventory}")
    out.line(f"known_hosts: {fleet.known_hosts}")
    out.line(f"key:         {fleet.key_file}")
    out.line(f"registry:    {fleet.registry_host} (robots: {fleet.registry_robot})")
    return 0


def cmd_down(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy import sim
    sim.down(progress=_progress(out), purge=args.purge)
    out.line("simulated fleet removed")
    return 0


def cmd_status(args: argparse.Namespace, out: Output) -> int:
    """Exit 0 when every robot runs and the registry answers, 3 otherwise."""
    from rosdeploy import sim
    current = sim.status()
    if out.as_json or args.status_json:
        out.document(_status_document(current))
        return 0 if current.running else 3
    if not current.robots:
        out.line(f"no simulated fleet in {current.home} (`rosdeploy sim up` starts one)")
        return 3
    out.table(["ROBOT", "ADDRESS", "ROS_DOMAIN_ID", "CONTAINER", "STATE"],
              [[r.robot.name, f"{r.robot.host}:{r.robot.ssh_port}", r.robot.ros_domain_id, r.robot.container,
                r.state] for r in current.robots])
    owner = f"started by sim, pid {current.registry_pid}" if current.registry_pid else "not started by sim"
    out.line(f"registry {current.registry}: {'up' if current.registry_up else 'DOWN'} ({owner})")
    return 0 if current.running else 3


def _status_document(current: sim.SimStatus) -> dict:
    return {"home": str(current.home), "running": current.running,
            "registry": {"address": current.registry, "up": current.registry_up, "pid": current.registry_pid},
            "robots": [{"name": r.robot.name, "address": r.robot.host, "ssh_port": r.robot.ssh_port,
                        "ros_domain_id": r.robot.ros_domain_id, "container": r.robot.container,
                        "state": r.state} for r in current.robots]}
