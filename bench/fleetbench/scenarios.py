"""The fleet scenarios, each run once per tool per round on the simulated robots.

One round for one tool, starting from clean robots:
  first deploy 1.0.0 -> no-op re-apply -> upgrade to 1.1.0 -> 1.2.0-bad (until the
  robots are back on 1.1.0 and healthy) -> emergency rollback of the whole fleet
  (rosdeploy `rollback`; Ansible redeploys the old version, 1.0.0).
Tool `floor` does the first deploy, upgrade and emergency rollback with no tool at all
(see `floor_steps`): the least work that leaves every robot on the version, healthy.
Every measured command must end as the scenario expects, and what the robots run
afterwards is checked from their own Docker engines (not from either tool's output).
"""
from __future__ import annotations

import base64
import io
import json
import tarfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from fleetbench import ansible as ans
from fleetbench.proc import BenchError, check, expect, rosdeploy_argv, timed

FIRST, UPGRADE, BAD = "1.0.0", "1.1.0", "1.2.0-bad"
SSH_FLOOR = "ssh-floor"     # rounds' key for the parallel `ssh true` floor (no-op scenario only)
FLOOR = "floor"             # the tool that is no tool: the switch by hand inside every robot (floor_steps)
FLOOR_ORDERED = "floor-ordered"     # the same, starting the services in depends_on order
SCENARIOS = ("first_deploy", "noop", "upgrade", "bad_release", "rollback")
TITLES = {
    "first_deploy": "first deploy 1.0.0, clean robots",
    "noop": "no-op re-apply",
    "upgrade": "upgrade 1.0.0 → 1.1.0",
    "bad_release": "1.2.0-bad → rolled back, healthy",
    "rollback": "emergency rollback, whole fleet",
}
KEEPER = "fleet-bench/layers:keep"
# Keep the demo images' layers on a robot under a local tag, then drop every demo
# tag: each round's pulls then fetch manifests (and any layer a tag adds), the same
# in every round, instead of 120 MB in round 1 and nothing after. Untagged (`<none>`)
# images other runs left are not names `docker rmi` takes: skipped.
UNTAG_SCRIPT = r'''
reg=$1
docker image inspect "$2" >/dev/null 2>&1 ||
    { docker pull -q "$reg/demo/driver:1.0.0" >/dev/null && docker tag "$reg/demo/driver:1.0.0" "$2"; }
tags=$(docker images --format '{{.Repository}}:{{.Tag}}' | grep "^$reg/demo/" | grep -v ':<none>$' || true)
[ -z "$tags" ] || docker rmi $tags >/dev/null
'''


@dataclass(frozen=True)
class SimBench:
    fleet: Path                     # the demo fleet file, used as it is
    inventory: Path                 # the sim's inventory
    robots: tuple[str, ...]
    project: str
    services: tuple[str, ...]       # what `up` starts (services without profiles)
    registry_robot: str
    runner: ans.Ansible
    extra: Mapping[str, Any]        # Ansible extra vars shared by every play
    env: Mapping[str, str] = field(default_factory=dict)
    ssh: tuple[tuple[str, ...], ...] = ()     # per robot: `ssh ... robot@host true`
    rosdeploy_args: tuple[str, ...] = ()      # appended to `rosdeploy apply` (tool `rosdeploy-at-once`)
    render_dir: Path | None = None  # `rosdeploy render` per version: <render_dir>/<version>/<robot>/
    deploy_root: str = ""           # the fleet's deploy root on the robots, "~" expanded (tool `floor`)

    @property
    def limit(self) -> str:
        return ":".join(self.robots)


@dataclass(frozen=True)
class Measure:
    seconds: float
    steps: tuple[dict, ...] = ()    # rosdeploy --json: per host {host, outcome, seconds, steps}
    wall_inside: float | None = None   # rosdeploy's own FleetResult.seconds


# ------------------------------------------------------------- robot state

def robot_services(robot: str, project: str) -> dict[str, dict]:
    """service -> {tag, status, health, id} from the robot's own engine (docker exec, as root)."""
    from rosdeploy import sim

    fmt = ('{"service":{{json (index .Config.Labels "com.docker.compose.service")}},"image":{{json .Config.Image}},'
           '"status":{{json .State.Status}},"id":{{json .Id}},'
           '"health":{{if .State.Health}}{{json .State.Health.Status}}{{else}}null{{end}}}')
    ids = sim.robot_exec(robot, ["docker", "ps", "-aq", "--filter",
                                 f"label=com.docker.compose.project={project}"]).stdout.split()
    if not ids:
        return {}
    out = sim.robot_exec(robot, ["docker", "inspect", "--format", fmt, *ids]).stdout
    rows = [json.loads(line) for line in out.splitlines() if line.strip()]
    return {r["service"]: {**r, "tag": r["image"].rsplit(":", 1)[-1]} for r in rows}


def verify(bench: SimBench, version: str, what: str, settle: float = 20.0) -> dict[str, dict]:
    """Every robot runs exactly the release's services, all at `version`, running and healthy.

    Untimed. rosdeploy may run a `starting` container's own check and finish before
    Docker's first tick (5 s in the demo images): Docker gets `settle` seconds to leave
    `starting`, then its verdict must be `healthy`.
    """
    deadline = time.monotonic() + settle
    seen = {robot: robot_services(robot, bench.project) for robot in bench.robots}
    while time.monotonic() < deadline and any(c["health"] == "starting" for s in seen.values() for c in s.values()):
        time.sleep(0.5)
        seen = {robot: robot_services(robot, bench.project) for robot in bench.robots}
    for robot, services in seen.items():
        wrong = {s: (c["tag"], c["status"], c["health"]) for s, c in services.items()
                 if (c["tag"], c["status"], c["health"] or "healthy") != (version, "running", "healthy")}
        if set(services) != set(bench.services) or wrong:
            raise BenchError(f"{what}: {robot} should run {version}, healthy; it runs "
                             f"{ {s: (c['tag'], c['status'], c['health']) for s, c in services.items()} }")
    return seen


def same_containers(before: Mapping[str, dict], after: Mapping[str, dict], what: str) -> None:
    ids = {r: {s: c["id"] for s, c in svc.items()} for r, svc in before.items()}
    if ids != {r: {s: c["id"] for s, c in svc.items()} for r, svc in after.items()}:
        raise BenchError(f"{what}: containers were recreated by a no-op")


def reset(bench: SimBench) -> None:
    """Clean robots: no compose project, no deploy root, no demo tags (layers kept)."""
    from rosdeploy import sim

    sim.reset()
    for robot in bench.robots:
        result = sim.robot_exec(robot, ["sh", "-c", UNTAG_SCRIPT, "untag", bench.registry_robot, KEEPER],
                                timeout=600)
        if result.returncode != 0:
            raise BenchError(f"{robot}: removing the demo tags failed: {result.stderr.strip()[-400:]}")


# --------------------------------------------------------------- rosdeploy

def rosdeploy(bench: SimBench, *args: str, codes: Sequence[int], what: str) -> Measure:
    shape = bench.rosdeploy_args if args[0] == "apply" else ()    # `rollback` does every robot at once anyway
    result = expect(timed(rosdeploy_argv("--json", *args, str(bench.fleet), "-i", str(bench.inventory),
                                         "--limit", bench.limit, "--yes", *shape), env=bench.env), codes, what)
    doc = json.loads(result.stdout)
    hosts = [*doc["hosts"], *doc.get("fleet_rollback", [])]
    steps = tuple({"host": h["host"], "outcome": h["outcome"], "seconds": h["seconds"], "steps": h["steps"]}
                  for h in hosts)
    return Measure(result.seconds, steps, doc.get("seconds"))


def outcomes(measure: Measure) -> set[str]:
    return {h["outcome"] for h in measure.steps}


# One step per scenario, in SCENARIOS order; each step checks what the robots run after it.
# `state` carries what a later step compares with (the no-op's container ids). A step that
# returns None has no measure for its scenario (the floor's bad release).
Step = Callable[[SimBench, dict], Measure | None]


def run_chain(bench: SimBench, steps: Mapping[str, Step], selected: Sequence[str]) -> dict[str, Measure]:
    """From clean robots, run the steps up to the last selected scenario (the earlier ones
    bring the robots to the state it starts from) and keep the selected ones' measures."""
    last = max(SCENARIOS.index(s) for s in selected)
    reset(bench)
    state: dict = {}
    got = {}
    for scenario in SCENARIOS[:last + 1]:
        measure = steps[scenario](bench, state)
        if scenario in selected and measure is not None:
            got[scenario] = measure
    return got


def _rd_first(bench: SimBench, state: dict) -> Measure:
    got = rosdeploy(bench, "apply", "--version", FIRST, codes=[0], what="rosdeploy first deploy")
    state["before"] = verify(bench, FIRST, "rosdeploy first deploy")
    return got


def _rd_noop(bench: SimBench, state: dict) -> Measure:
    got = rosdeploy(bench, "apply", "--version", FIRST, codes=[0], what="rosdeploy no-op")
    if outcomes(got) != {"unchanged"}:
        raise BenchError(f"rosdeploy no-op re-apply did something: {outcomes(got)}")
    same_containers(state["before"], verify(bench, FIRST, "rosdeploy no-op"), "rosdeploy no-op")
    return got


def _rd_upgrade(bench: SimBench, state: dict) -> Measure:
    got = rosdeploy(bench, "apply", "--version", UPGRADE, codes=[0], what="rosdeploy upgrade")
    verify(bench, UPGRADE, "rosdeploy upgrade")
    return got


def _rd_bad(bench: SimBench, state: dict) -> Measure:
    got = rosdeploy(bench, "apply", "--version", BAD, codes=[3, 4], what="rosdeploy bad release")
    verify(bench, UPGRADE, "rosdeploy bad release (must be back on 1.1.0)")
    return got


def _rd_rollback(bench: SimBench, state: dict) -> Measure:
    got = rosdeploy(bench, "rollback", codes=[0], what="rosdeploy rollback")
    verify(bench, FIRST, "rosdeploy emergency rollback")
    return got


ROSDEPLOY_STEPS: dict[str, Step] = {"first_deploy": _rd_first, "noop": _rd_noop, "upgrade": _rd_upgrade,
                                    "bad_release": _rd_bad, "rollback": _rd_rollback}


def rosdeploy_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(bench, ROSDEPLOY_STEPS, selected)


# The demo fleet file deploys a canary robot first, then the rest (`rollout.waves: [1, "100%"]`);
# minimal.yml does every robot at once. This tool is rosdeploy in minimal.yml's shape: the same
# fleet file and gate, `--waves 100%` (what `rollback` and an emergency do anyway).
AT_ONCE = ("--waves", "100%")


def rosdeploy_at_once_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(replace(bench, rosdeploy_args=AT_ONCE), ROSDEPLOY_STEPS, selected)


# ----------------------------------------------------------------- Ansible

def policy_vars(fleet: Mapping[str, Any]) -> dict[str, Any]:
    """The fleet file's waves and max_fail, as Ansible's serial and max_fail_percentage."""
    rollout = fleet.get("rollout") or {}
    waves = [str(w) if isinstance(w, str) else int(w) for w in rollout.get("waves", ["100%"])]
    max_fail = rollout.get("max_fail", 0)
    if isinstance(max_fail, str) and max_fail.endswith("%"):
        percent = float(max_fail[:-1])
    elif int(max_fail) == 0:
        percent = 0.0
    else:
        raise BenchError(f"rollout.max_fail {max_fail!r}: only 0 or N% map onto Ansible's max_fail_percentage")
    return {"waves": waves, "max_fail_percentage": percent}


def play(bench: SimBench, version: str, codes: Sequence[int], what: str, playbook: str = "deploy.yml",
         **extra: Any) -> Measure:
    result = ans.require(bench.runner.play({**bench.extra, "version": version, **extra},
                                           forks=max(len(bench.robots), 5), limit=bench.limit, playbook=playbook),
                         codes, what)
    return Measure(result.seconds)


def ansible_steps(playbook: str, name: str) -> dict[str, Step]:
    """deploy.yml (equal work: release dirs, health check, rescue) or minimal.yml (template,
    pull, up --wait; a bad release is detected, not rolled back)."""
    minimal = playbook == "minimal.yml"

    def first(bench: SimBench, state: dict) -> Measure:
        got = play(bench, FIRST, [0], f"{name} first deploy", playbook)
        state["before"] = verify(bench, FIRST, f"{name} first deploy")
        return got

    def noop(bench: SimBench, state: dict) -> Measure:
        got = play(bench, FIRST, [0], f"{name} no-op", playbook)
        same_containers(state["before"], verify(bench, FIRST, f"{name} no-op"), f"{name} no-op")
        return got

    def upgrade(bench: SimBench, state: dict) -> Measure:
        got = play(bench, UPGRADE, [0], f"{name} upgrade", playbook)
        verify(bench, UPGRADE, f"{name} upgrade")
        return got

    def bad(bench: SimBench, state: dict) -> Measure:
        got = play(bench, BAD, [2], f"{name} bad release", playbook)
        if not minimal:     # the minimal playbook only detects: the bad release stays
            verify(bench, UPGRADE, f"{name} bad release (must be back on 1.1.0)")
        return got

    def rollback(bench: SimBench, state: dict) -> Measure:
        # An emergency: every robot at once, like `rosdeploy rollback` (no canary wave).
        got = play(bench, FIRST, [0], f"{name} redeploy of the old version", playbook, waves=["100%"])
        verify(bench, FIRST, f"{name} redeploy of the old version")
        return got

    return {"first_deploy": first, "noop": noop, "upgrade": upgrade, "bad_release": bad, "rollback": rollback}


def ansible_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(bench, ansible_steps("deploy.yml", "Ansible"), selected)


def ansible_minimal_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(bench, ansible_steps("minimal.yml", "Ansible minimal"), selected)


def render_versions(fleet: Path, inventory: Path, out: Path, versions: Sequence[str]) -> Path:
    """`rosdeploy render` per version: the exact files both tools deploy."""
    for version in versions:
        check(rosdeploy_argv("render", str(fleet), "-i", str(inventory), "--version", version,
                             "--out", str(out / version)), what=f"rosdeploy render --version {version}")
    return out


# ------------------------------------------------------------------- floor

# Runs inside a robot as root. $1: the version's dir, $2: the project, $3: 1 to pull first;
# then the levels to start one after the other, each a comma-separated list of services, or
# `*` for every container of the project at once. Prints the robot's clock (/proc/uptime) at
# the start and after each phase. As in bench/rollback_floor.py: no ROS probe, verdict files
# read from the robot's own disk every 20 ms.
FLOOR_SCRIPT = r"""
dir=$1; project=$2; pull=$3; shift 3
cd "$dir" || exit 4
compose() { docker compose -p "$project" -f compose.yml "$@"; }
if [ "$pull" = 0 ]; then     # a rollback: the images must be here already, else `up` would pull
    docker image inspect $(compose config --images) >/dev/null 2>&1 || { echo "images of $dir missing" >&2; exit 7; }
fi
clock() { read -r u _ </proc/uptime; echo "$u"; }
t0=$(clock)
[ "$pull" = 0 ] || compose pull --quiet >/dev/null 2>&1 || { echo "pull failed in $dir" >&2; exit 5; }
t1=$(clock)
running=$(docker ps -q --filter "label=com.docker.compose.project=$project")
[ -z "$running" ] || docker stop $running >/dev/null
t2=$(clock)
compose up --no-start --remove-orphans >/dev/null 2>&1 || { echo "up --no-start failed in $dir" >&2; exit 5; }
t3=$(clock)
marks="$t0 $t1 $t2 $t3"
for level in "$@"; do
  if [ "$level" = "*" ]; then
    ids=$(docker ps -aq --filter "label=com.docker.compose.project=$project")
  else
    ids=
    for svc in $(echo "$level" | tr , ' '); do
      ids="$ids $(docker ps -aq --filter "label=com.docker.compose.project=$project" \
                                --filter "label=com.docker.compose.service=$svc")"
    done
  fi
  files=
  for id in $ids; do
    f="$(docker inspect -f '{{.GraphDriver.Data.UpperDir}}' "$id")/tmp/rosdeploy-health"
    rm -f "$f"; files="$files $f"
  done
  for id in $ids; do docker start "$id" >/dev/null & done; wait
  t=$(clock); marks="$marks $t"
  end=$(( ${t%.*} + 120 ))
  while :; do
    ok=0; n=0
    for f in $files; do n=$((n + 1)); [ -r "$f" ] && read -r v _ <"$f" && [ "$v" = healthy ] && ok=$((ok + 1)); done
    [ "$ok" -eq "$n" ] && break
    now=$(clock); [ "${now%.*}" -lt "$end" ] || { echo "not healthy within 120 s in $dir" >&2; exit 6; }
    sleep 0.02
  done
  marks="$marks $(clock)"
done
echo "$marks"
"""
FLOOR_PHASES = ("pull", "stop", "create")     # then "start" and "healthy" per level
ALL_AT_ONCE = ("*",)
FLOOR_SETTLE = 3.0      # untimed seconds before each timed step: the previous version's nodes warmed up
LOG_MODE = 0o1777       # minimal.yml's log directories: sticky, world-writable like /tmp


def floor_dir(bench: SimBench, version: str) -> str:
    """Two levels below the project dir, as rosdeploy's releases/<id>/ and minimal.yml's
    minimal/app/: the compose file mounts ../../store/... and ../../logs/<service>."""
    return f"{bench.deploy_root}/{bench.project}/floor/{version}"


def floor_files(bench: SimBench, robot: str, version: str) -> str:
    """The robot's rendered files of `version` as a base64 tar rooted at the project dir:
    floor/<version>/{compose.yml,.env,fastdds.xml}, store/<digest>/..., logs/<service>/."""
    if bench.render_dir is None:
        raise BenchError("tool floor: no render_dir")
    source = bench.render_dir / version / robot
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        def add_dir(name: str, mode: int) -> None:
            info = tarfile.TarInfo(name)
            info.type, info.mode, info.mtime = tarfile.DIRTYPE, mode, int(time.time())
            tar.addfile(info)

        for name in ("floor", f"floor/{version}", "store", "logs"):
            add_dir(name, 0o755)
        for service in bench.services:
            add_dir(f"logs/{service}", LOG_MODE)
        for name in ("compose.yml", ".env", "fastdds.xml"):
            tar.add(source / name, f"floor/{version}/{name}")
        for path in sorted((source / "store").rglob("*")):
            tar.add(path, f"store/{path.relative_to(source / 'store')}", recursive=False)
    return base64.b64encode(buf.getvalue()).decode()


def copy_floor_files(bench: SimBench, version: str) -> None:
    """Untimed: the version's files into every robot, as the SSH user (minimal.yml's owner)."""
    from rosdeploy import sim

    def one(robot: str) -> None:
        project_dir = f"{bench.deploy_root}/{bench.project}"
        result = sim.robot_exec(robot, ["sh", "-c", 'mkdir -p "$1" && base64 -d | tar -x -p -C "$1"', "sh",
                                        project_dir], user="robot", input=floor_files(bench, robot, version))
        if result.returncode != 0:
            raise BenchError(f"floor: copying {version}'s files into {robot}: {result.stderr.strip()[-400:]}")

    with ThreadPoolExecutor(len(bench.robots)) as pool:
        list(pool.map(one, bench.robots))


def start_levels(bench: SimBench, version: str) -> tuple[str, ...]:
    """The release's services in depends_on order, as the floor script's levels: each level
    the services whose dependencies are all in earlier levels ("driver", "perception")."""
    import yaml

    if bench.render_dir is None:
        raise BenchError("tool floor: no render_dir")
    compose = yaml.safe_load((bench.render_dir / version / bench.robots[0] / "compose.yml").read_text())
    needs = {name: set(svc.get("depends_on") or ()) for name, svc in compose["services"].items()
             if name in bench.services}
    levels: list[str] = []
    placed: set[str] = set()
    while len(placed) < len(needs):
        level = sorted(name for name, deps in needs.items() if name not in placed and deps & set(needs) <= placed)
        if not level:
            raise BenchError(f"{version}: depends_on has a cycle among {sorted(set(needs) - placed)}")
        levels.append(",".join(level))
        placed.update(level)
    return tuple(levels)


def floor_switch(bench: SimBench, version: str, pull: bool, what: str, ordered: bool = False) -> Measure:
    """Timed: the switch to `version` as root inside every robot at once (one `docker exec`
    each, in threads). The wall time is the controller's; each robot's phases come from
    its own clock, as steps {host, outcome, seconds, steps} in rosdeploy's --json shape."""
    from rosdeploy import sim

    levels = start_levels(bench, version) if ordered else ALL_AT_ONCE
    copy_floor_files(bench, version)
    time.sleep(FLOOR_SETTLE)

    def one(robot: str) -> tuple[str, Any]:
        return robot, sim.robot_exec(robot, ["sh", "-c", FLOOR_SCRIPT, "sh", floor_dir(bench, version),
                                             bench.project, "1" if pull else "0", *levels], timeout=300)

    started = time.monotonic()
    with ThreadPoolExecutor(len(bench.robots)) as pool:
        done = list(pool.map(one, bench.robots))
    seconds = time.monotonic() - started
    steps: list[dict[str, Any]] = []
    for robot, result in done:
        if result.returncode != 0:
            raise BenchError(f"{what}: {robot}: exit {result.returncode}: {result.stderr.strip()[-400:]}")
        t0, *marks = (float(x) for x in result.stdout.split())
        names = [*FLOOR_PHASES, *(f"{phase} {level}" for level in levels for phase in ("start", "healthy"))]
        phases = [{"name": name, "seconds": round(b - a, 3)}
                  for name, a, b in zip(names, [t0, *marks[:-1]], marks, strict=True)]
        steps.append({"host": robot, "outcome": "floor", "seconds": round(marks[-1] - t0, 3), "steps": phases})
    inside = max(s["seconds"] for s in steps)
    return Measure(seconds, tuple(steps), inside)


def floor_steps(ordered: bool = False) -> dict[str, Step]:
    """No tool at all, the lower bound of any tool on these robots (`ordered`: of any tool
    that starts the services in their depends_on order, each level once the one before it
    is healthy, as rosdeploy and Compose do).

    Untimed before each step: the version's rendered files (`rosdeploy render`, the same
    files both Ansible playbooks deploy) are copied into every robot, with the log
    directories minimal.yml creates (mode 1777), and the machine gets FLOOR_SETTLE seconds.
    Copying files is not what the floor measures. Timed: as root inside every robot at once
    (`docker exec`, no SSH, no Python on the robot): for the first deploy and the upgrade,
    `compose pull` while the old version runs; then stop the old containers, `compose up
    --no-start --remove-orphans`, `docker start` every container in parallel, and poll every
    container's verdict file (its UpperDir/tmp/rosdeploy-health) every 20 ms until all say
    healthy. The rollback: the same without the pull (1.0.0's images are still on the robots).
    Unordered, no depends_on order (every container started at once) and no ROS probe: below
    any tool that respects depends_on (rosdeploy, Compose's --wait) or waits for Docker's
    health status (first tick 5 s after the start). Ordered: the same, level by level.
    The no-op is nothing (0 s); the bad release is skipped (no measure), so the rollback
    starts from robots on 1.1.0. Same compose project and deploy root as the other tools:
    `verify` checks Docker's own verdict and tags after each step, `reset` removes it all.
    """

    def first(bench: SimBench, state: dict) -> Measure:
        got = floor_switch(bench, FIRST, True, "floor first deploy", ordered)
        verify(bench, FIRST, "floor first deploy")
        return got

    def noop(bench: SimBench, state: dict) -> Measure:
        return Measure(0.0)

    def upgrade(bench: SimBench, state: dict) -> Measure:
        got = floor_switch(bench, UPGRADE, True, "floor upgrade", ordered)
        verify(bench, UPGRADE, "floor upgrade")
        return got

    def bad(bench: SimBench, state: dict) -> None:
        return None

    def rollback(bench: SimBench, state: dict) -> Measure:
        got = floor_switch(bench, FIRST, False, "floor rollback", ordered)
        verify(bench, FIRST, "floor rollback")
        return got

    return {"first_deploy": first, "noop": noop, "upgrade": upgrade, "bad_release": bad, "rollback": rollback}


def floor_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(bench, floor_steps(), selected)


def floor_ordered_round(bench: SimBench, selected: Sequence[str] = SCENARIOS) -> dict[str, Measure]:
    return run_chain(bench, floor_steps(ordered=True), selected)


Round = Callable[[SimBench, Sequence[str]], dict[str, Measure]]
TOOLS: dict[str, Round] = {"rosdeploy": rosdeploy_round, "rosdeploy-at-once": rosdeploy_at_once_round,
                           "ansible": ansible_round, "ansible-minimal": ansible_minimal_round,
                           FLOOR: floor_round, FLOOR_ORDERED: floor_ordered_round}
