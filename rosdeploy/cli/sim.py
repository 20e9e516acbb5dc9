"""`rosdeploy sim up|down|status`: a simulated fleet on this machine (see rosdeploy.sim)."""
from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

from rosdeploy.cli.common import add_command, duration, positive_int
from rosdeploy.errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_PARTIAL
from rosdeploy.output import Output

if TYPE_CHECKING:
    from rosdeploy import sim

# `rosdeploy.sim` is imported by the handlers: every command builds the whole parser, and
# the others (an emergency rollback among them) need none of it.

SIM_CODES = (EXIT_OK, EXIT_PARTIAL, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED)
ROBOT_HELP = "a simulated robot's name, as `rosdeploy sim status` lists them (robot1, robot2, ...)"
SIM_MEANINGS = {EXIT_PARTIAL: "the simulated fleet failed: it could not be brought up or down, or is not running"}


def register(sub: argparse._SubParsersAction) -> None:
    parser = add_command(sub, "sim", "a simulated robot fleet on this machine (Docker-in-Docker robots)",
                         "Robots are containers with sshd and their own Docker engine; state lives in "
                         "$ROSDEPLOY_SIM_HOME (default ~/.rosdeploy/sim).",
                         SIM_CODES, "rosdeploy sim up --robots 3", SIM_MEANINGS)
    actions = parser.add_subparsers(dest="sim_command", metavar="ACTION", required=True)

    up = add_command(actions, "up", "start the robots, the registry, and build the demo images if needed",
                     "Start N robots and the registry (reusing what runs), building the demo images on first "
                     "use; prints the inventory, known_hosts and key to deploy with.",
                     SIM_CODES, "rosdeploy sim up --robots 3", SIM_MEANINGS)
    up.add_argument("--robots", type=positive_int, default=3, metavar="N", help="number of robots (default 3)")
    up.set_defaults(func=cmd_up, acts=True)

    down = add_command(actions, "down", "remove the robots and the registry the simulator started",
                       "Remove the robot containers and their volumes, and stop the registry if the simulator "
                       "started it.", SIM_CODES, "rosdeploy sim down --purge", SIM_MEANINGS)
    down.add_argument("--purge", action="store_true",
                      help="also remove the simulator's images, registry data and state dir")
    down.set_defaults(func=cmd_down, acts=True)

    status = add_command(actions, "status", "list the robots, their addresses and state",
                         "List the simulated robots, their SSH addresses and container state, and whether the "
                         "registry answers.", SIM_CODES, "rosdeploy sim status --json",
                         {**SIM_MEANINGS, EXIT_OK: "every robot runs and the registry answers",
                          EXIT_PARTIAL: "no fleet, a robot not running, or the registry down"})
    status.set_defaults(func=cmd_status)
    _register_faults(actions)


def _register_faults(actions: argparse._SubParsersAction) -> None:
    """Field faults to rehearse on: a cut link, a robot without its registry, a busy robot, a reboot."""
    cut = add_command(actions, "cut", "drop a robot's SSH link (the robot keeps running) until `sim heal`",
                      "Every packet to the robot's sshd is dropped, on open connections too, as when a robot "
                      "roams out of Wi-Fi range.", SIM_CODES, "rosdeploy sim cut robot2 --for 2s", SIM_MEANINGS)
    cut.add_argument("robot", metavar="ROBOT", help=ROBOT_HELP)
    cut.add_argument("--for", dest="seconds", type=duration, default=0.0, metavar="DURATION",
                     help="heal by itself after this long (e.g. 2s: a Wi-Fi blip)")
    cut.set_defaults(func=cmd_fault, fault="cut", acts=True)
    isolate = add_command(actions, "isolate", "cut a robot off from the registry; its SSH link still works",
                          "Drop the robot's traffic to the registry, so pulls fail while SSH works.",
                          SIM_CODES, "rosdeploy sim isolate robot2 --from registry", SIM_MEANINGS)
    isolate.add_argument("robot", metavar="ROBOT", help=ROBOT_HELP)
    isolate.add_argument("--from", dest="target", choices=["registry"], default="registry", metavar="WHAT",
                         help="what the robot loses: registry (the only one so far, the default)")
    isolate.set_defaults(func=cmd_fault, fault="isolate", acts=True)
    heal = add_command(actions, "heal", "undo `sim cut` and `sim isolate` on a robot",
                       "Restore a robot's SSH link and its way to the registry.", SIM_CODES,
                       "rosdeploy sim heal robot2", SIM_MEANINGS)
    heal.add_argument("robot", metavar="ROBOT", help=ROBOT_HELP)
    heal.set_defaults(func=cmd_fault, fault="heal", acts=True)
    busy = add_command(actions, "busy", "set the demo driver's /robot_mode to BUSY (on) or IDLE (off)",
                       "Set the demo driver's /robot_mode topic to BUSY (on) or IDLE (off).", SIM_CODES,
                       "rosdeploy sim busy robot2 on", SIM_MEANINGS)
    busy.add_argument("robot", metavar="ROBOT", help=ROBOT_HELP)
    busy.add_argument("state", choices=["on", "off"], metavar="on|off", help="on: BUSY; off: IDLE again")
    busy.set_defaults(func=cmd_fault, fault="busy", acts=True)
    reboot = add_command(actions, "reboot", "restart a robot (its engine, sshd and containers) and wait for it",
                         "Restart a robot (its engine, sshd and containers) and wait until it answers again.",
                         SIM_CODES, "rosdeploy sim reboot robot2", SIM_MEANINGS)
    reboot.add_argument("robot", metavar="ROBOT", help=ROBOT_HELP)
    reboot.set_defaults(func=cmd_fault, fault="reboot", acts=True)


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
    """Exit 0 when every robot runs and the registry answers, EXIT_PARTIAL (3) otherwise."""
    from rosdeploy import sim
    current = sim.status()
    if out.as_json:
        out.document(_status_document(current))
        return EXIT_OK if current.running else EXIT_PARTIAL
    if not current.robots:
        out.line(f"no simulated fleet in {current.home} (`rosdeploy sim up` starts one)")
        return EXIT_PARTIAL
    out.table(["ROBOT", "ADDRESS", "ROS_DOMAIN_ID", "CONTAINER", "STATE"],
              [[r.robot.name, f"{r.robot.host}:{r.robot.ssh_port}", r.robot.ros_domain_id, r.robot.container,
                r.state] for r in current.robots])
    owner = f"started by sim, pid {current.registry_pid}" if current.registry_pid else "not started by sim"
    out.line(f"registry {current.registry}: {'up' if current.registry_up else 'DOWN'} ({owner})")
    return EXIT_OK if current.running else EXIT_PARTIAL


def _status_document(current: sim.SimStatus) -> dict:
    return {"home": str(current.home), "running": current.running,
            "registry": {"address": current.registry, "up": current.registry_up, "pid": current.registry_pid},
            "robots": [{"name": r.robot.name, "address": r.robot.host, "ssh_port": r.robot.ssh_port,
                        "ros_domain_id": r.robot.ros_domain_id, "container": r.robot.container,
                        "state": r.state} for r in current.robots]}
