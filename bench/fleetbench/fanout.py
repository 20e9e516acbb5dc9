"""Fan-out cost: `rosdeploy status`, no-op `rosdeploy apply` and Ansible's no-op
playbook over N lightweight SSH targets (host sshd processes, see sshd.py).

Every target must be a true no-op for both tools:
  - rosdeploy: every target gets the same release id. The fan-out fleet overrides
    the templates with copies of the built-in ones that leave the robot's name out
    of the header comments and use one logrotate path (the only per-robot text in
    the built-ins); all targets share one ros_domain_id on distinct ros_network
    values. The release is deployed for real to target 1 with the host's engine
    (project `fanout`, images from 127.0.0.1:5000), then target 1's deploy root is
    copied (`cp -a`) to every other target's root: each sees `current` = that
    release and the same healthy containers.
  - Ansible: the playbook deploys for real to target 1, then every target points at
    that one deploy root. On the single host engine a compose project has one
    working directory; a target with its own copy would make compose recreate the
    containers (their bind-mount paths would differ). On real robots each has its own.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import yaml

from rosdeploy import keeper

from fleetbench import ansible as ans
from fleetbench.proc import BenchError, Timed, check, expect, log, rosdeploy_argv, timed
from fleetbench.sshd import (SshdFarm, Target, ensure_user, keygen, make_targets, public_key, remove_user,
                             write_known_hosts)

PROJECT = "fanout"
DOMAIN_ID = 9                 # 0-101 (no ephemeral-port clash), not used by the sim robots (11..)
REGISTRY = "127.0.0.1:5000"   # as the host engine reaches the sim registry
TEMPLATE_DIR = Path(__file__).resolve().parents[2] / "templates"
# The demo image's own check, with a timeout and retries that survive minutes of a saturated CPU.
TOLERANT_HEALTHCHECK = {"test": ["CMD", "/opt/demo/healthcheck"], "interval": "5s", "timeout": "30s",
                        "retries": 12, "start_period": "15s"}
HOST_NAME_EXPR = "host.name"
LOGS_EXPR = "logs_glob"


@dataclass(frozen=True)
class Fanout:
    work: Path
    user: str
    targets: tuple[Target, ...]
    sizes: tuple[int, ...]
    key: Path
    known_hosts: Path
    fleet: Path
    render_dir: Path
    ansible_root: Path

    def group(self, n: int) -> str:
        return f"fan{n}"

    def root(self, target: Target) -> Path:
        return self.work / "roots" / target.name / "rosdeploy"


# ----------------------------------------------------------------- files

def write_templates(folder: Path) -> Path:
    """The built-in templates without per-robot text, so every target renders the same bytes."""
    folder.mkdir(parents=True, exist_ok=True)
    for source in sorted(TEMPLATE_DIR.glob("*.j2")):
        text = source.read_text().replace(HOST_NAME_EXPR, "'fan-out target'")
        text = text.replace(LOGS_EXPR, f"'/var/log/ros/{PROJECT}/*/*.log'")
        (folder / source.name).write_text(text)
    return folder


def fleet_data(demo: dict[str, Any], inventory: Path, templates: Path, known_hosts: Path,
               forks: int) -> dict[str, Any]:
    """The demo fleet file for the fan-out targets: its services, no devices, the host's registry."""
    data = json.loads(json.dumps(demo))           # deep copy of plain YAML data
    data.update(project=PROJECT, inventory=str(inventory), templates=str(templates), registry=REGISTRY,
                version="1.0.0")
    data.setdefault("ssh", {})["known_hosts"] = str(known_hosts)
    data.setdefault("rollout", {})["forks"] = forks
    data.pop("deploy_root", None)                 # each target has rosdeploy_deploy_root
    for service in data["services"].values():
        service.pop("devices", None)
        # 100 targets' SSH sessions (and Ansible's modules) share this machine's 2 cores with
        # the demo nodes; at their normal threshold (half the nominal rate) and the image's
        # check (3 s timeout, 2 retries) the health flaps to unhealthy under that load and the
        # no-op would become a rollback, for either tool.
        service.setdefault("environment", {})["DEMO_HEALTH_MIN_HZ"] = "0.5"
        service["healthcheck"] = dict(TOLERANT_HEALTHCHECK)
    return data


def inventory_data(fanout_work: Path, user: str, targets: Sequence[Target], sizes: Sequence[int], key: Path,
                   known_hosts: Path) -> dict[str, Any]:
    hosts = {t.name: {"ansible_host": "127.0.0.1", "ansible_port": t.port, "ros_domain_id": DOMAIN_ID,
                      "ros_network": f"fanout-{t.name}",
                      "rosdeploy_deploy_root": str(fanout_work / "roots" / t.name / "rosdeploy")}
             for t in targets}
    groups = {f"fan{n}": {"hosts": {t.name: None for t in targets[:n]}} for n in sizes}
    return {"all": {"vars": {"ansible_user": user, "ansible_ssh_private_key_file": str(key),
                             "rosdeploy_known_hosts": str(known_hosts)},
                    "hosts": hosts, "children": groups}}


def prepare(work: Path, demo: dict[str, Any], sizes: Sequence[int], base_port: int) -> tuple[Fanout, SshdFarm]:
    """The login user, keys, known_hosts, the fan-out fleet file and inventory; the (not yet
    started) sshd farm. Undo with `teardown`."""
    work.mkdir(parents=True, exist_ok=True)
    for folder in (work.parent, work):
        folder.chmod(0o755)          # the login user reaches its home and deploy roots through them
    user = ensure_user(work / "home")
    (work / "roots").mkdir()
    shutil.chown(work / "roots", user, user)
    targets = tuple(make_targets(work, max(sizes), base_port))
    key = keygen(work / "id_ed25519", "fleet-bench")
    known_hosts = write_known_hosts(work / "known_hosts", targets)
    inventory = work / "inventory.yml"
    inventory.write_text(yaml.safe_dump(inventory_data(work, user, targets, sizes, key, known_hosts),
                                        sort_keys=False))
    fleet = work / "fanout.yml"
    data = fleet_data(demo, inventory, write_templates(work / "templates"), known_hosts, max(sizes))
    fleet.write_text(yaml.safe_dump(data, sort_keys=False))
    fanout = Fanout(work, user, targets, tuple(sizes), key, known_hosts, fleet, work / "render",
                    work / "roots" / "shared")
    return fanout, SshdFarm(work, targets, public_key(key))


def render_identical(fanout: Fanout) -> str:
    """Render every target's release; they must all have one release id (else no true no-op)."""
    out = fanout.render_dir / "1.0.0"
    result = check(rosdeploy_argv("--json", "render", str(fanout.fleet), "--out", str(out)),
                   what="rosdeploy render (fan-out fleet)")
    ids = {robot["release"] for robot in json.loads(result.stdout)["robots"]}
    if len(ids) != 1:
        raise BenchError(f"fan-out targets render {len(ids)} different releases ({sorted(ids)[:3]}...): a no-op "
                         "apply would redeploy; the templates carry per-robot text the override misses")
    return ids.pop()


# ------------------------------------------------------------ rosdeploy side

def deploy_first_target(fanout: Fanout) -> None:
    """A real deploy to target 1, then its deploy root copied to every other target."""
    first = fanout.targets[0]
    result = timed(rosdeploy_argv("--json", "apply", str(fanout.fleet), "--yes", "--limit", first.name))
    expect(result, [0], f"rosdeploy apply to fan-out target {first.name}")
    for target in fanout.targets[1:]:
        dest = fanout.root(target)
        shutil.rmtree(dest.parent, ignore_errors=True)
        dest.parent.mkdir(parents=True)
        check(["cp", "-a", str(fanout.root(first)), str(dest)], what=f"copying the deploy root to {target.name}")


def rosdeploy_status(fanout: Fanout, n: int, held: bool) -> Timed:
    """`held`: the connections the previous command left with the keeper (ssh.persist, as
    Ansible's ControlPersist); else the keeper is stopped first and this run connects."""
    if not held:
        check(rosdeploy_argv("connections", "--close"), what="stop the connection keeper")
    pid, before = keeper_cpu()
    result = timed(rosdeploy_argv("--json", "status", str(fanout.fleet), "--limit", fanout.group(n)))
    pid_after, after = keeper_cpu()
    # The keeper is no child the run waits for: add its CPU, so the figure is the controller's.
    result = replace(result, cpu=result.cpu + after - (before if pid == pid_after else 0.0))
    expect(result, [0], f"rosdeploy status over {n} fan-out targets")
    rows = json.loads(result.stdout)["robots"]
    bad = [r["host"] for r in rows if not (r["reachable"] and r["healthy"] and r["drift"] is False)]
    if len(rows) != n or bad:
        raise BenchError(f"status over {n} targets: {len(rows)} rows, not healthy/in sync: {bad[:5]}")
    return result


def keeper_cpu() -> tuple[int | None, float]:
    """The running keeper's pid and its user+sys CPU seconds so far."""
    reply = keeper.ask({"op": "list"})
    if not reply:
        return None, 0.0
    fields = Path(f"/proc/{reply['pid']}/stat").read_text().rsplit(")", 1)[1].split()
    return reply["pid"], (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rosdeploy_noop(fanout: Fanout, n: int) -> Timed:
    result = timed(rosdeploy_argv("--json", "apply", str(fanout.fleet), "--yes", "--limit", fanout.group(n)))
    expect(result, [0], f"no-op rosdeploy apply over {n} fan-out targets")
    outcomes = {h["outcome"] for h in json.loads(result.stdout)["hosts"]}
    if outcomes != {"unchanged"}:
        raise BenchError(f"no-op apply over {n} targets was not a no-op: outcomes {sorted(outcomes)}")
    return result


# -------------------------------------------------------------- Ansible side

def ansible_inventory(fanout: Fanout) -> Path:
    hosts = [ans.InventoryHost(t.name, "127.0.0.1", t.port, str(fanout.ansible_root)) for t in fanout.targets]
    groups = {fanout.group(n): [t.name for t in fanout.targets[:n]] for n in fanout.sizes}
    return ans.write_inventory(fanout.work / "ansible-inventory.yml", hosts, user=fanout.user, key_file=fanout.key,
                               known_hosts=fanout.known_hosts, groups=groups)


def ansible_extra(fanout: Fanout, policy: dict[str, Any], services: list[str], health_timeout: int) -> dict[str, Any]:
    return {"project": PROJECT, "version": "1.0.0", "services": services, "render_dir": str(fanout.render_dir),
            "health_timeout": health_timeout, **policy}


def ansible_deploy_first_target(fanout: Fanout, runner: ans.Ansible, extra: dict[str, Any]) -> None:
    remove_project()          # rosdeploy's containers go; Ansible starts its own from its release dir
    first = fanout.targets[0].name
    ans.require(runner.play(extra, forks=1, limit=first), [0], f"Ansible deploy to fan-out target {first}")


def ansible_noop(fanout: Fanout, runner: ans.Ansible, extra: dict[str, Any], n: int) -> Timed:
    result = ans.require(runner.play(extra, forks=n, limit=fanout.group(n)), [0],
                         f"Ansible no-op over {n} fan-out targets")
    changed = [line for line in result.stdout.splitlines() if ": ok=" in line and "changed=0" not in line]
    if changed:
        raise BenchError(f"Ansible no-op over {n} targets changed something: {changed[:3]}")
    return result


def settle(timeout: float = 60.0) -> None:
    """Wait (untimed) until the fan-out containers are healthy again: a burst of 100 SSH
    sessions on 2 cores can starve the demo nodes below their health threshold for a while."""
    deadline = time.monotonic() + timeout
    while True:
        ids = timed(["docker", "ps", "-q", "--filter", f"label=com.docker.compose.project={PROJECT}"]).stdout.split()
        states = (timed(["docker", "inspect", "--format", "{{.State.Health.Status}}", *ids]).stdout.split()
                  if ids else [])
        if states and all(s == "healthy" for s in states):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"the fan-out containers are not healthy after {timeout:.0f} s: {states}")
        time.sleep(1.0)


# ---------------------------------------------------------------- teardown

def teardown(farm: SshdFarm) -> None:
    """Everything `prepare` and the runs started: containers, sshd processes, the login user."""
    remove_project()
    farm.stop()
    remove_user()


def remove_project() -> None:
    """Remove the fan-out project's containers from the host engine."""
    ids = timed(["docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={PROJECT}"]).stdout.split()
    if ids:
        check(["docker", "rm", "-f", *ids], what="removing the fan-out containers")
    if ids:
        log(f"removed {len(ids)} fan-out container(s)")
