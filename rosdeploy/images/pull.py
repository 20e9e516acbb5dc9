"""The pull step of one robot: the pinned images under their normal names, by its route.

    via registry: the robot pulls `registry/repo@digest` itself and tags it
    via ssh:      the robot pulls `127.0.0.1:<forward>/repo@digest` (see forward.py), tags it,
                  and drops the forward's name

Either way the robot's engine checks every blob against its digest while it pulls, and
the script then checks that the normal name holds the pinned image id.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from rosdeploy.commands import Command, script
from rosdeploy.errors import ConnectError
from rosdeploy.images.forward import Forward, Limiter, Meter
from rosdeploy.images.refs import Pin, human_bytes, split_ref
from rosdeploy.model import RenderedRelease
from rosdeploy.results import Step
from rosdeploy.transport import Result

if TYPE_CHECKING:
    from rosdeploy.deploy import RobotRun

PULL_SCRIPT = (Path(__file__).parent / "pull.sh").read_text()
UNREACHABLE = ("no route to host", "connection refused", "i/o timeout", "no such host", "network is unreachable",
               "server misbehaving", "dial tcp")


def command(pins: list[Pin], registry: str | None, timeout: float | None,
            stages: dict[str, tuple[str, ...]] | None = None) -> Command:
    """`registry`: the name robots pull from (their registry host, or 127.0.0.1:<port> of a forward).
    `stages`: pin digest -> the stage manifests to pull first (relay.py), for a resumable transfer."""
    args = []
    for pin in pins:
        host = registry if registry is not None else split_ref(pin.ref)[0]
        source = f"{host}/{pin.repository}@{pin.digest}" if host else f"{pin.repository}@{pin.digest}"
        args += [pin.ref, source, pin.image_id or f"@{pin.digest}", ",".join((stages or {}).get(pin.digest, ())) or "-"]
    return script("pull", PULL_SCRIPT, *args, timeout=timeout)


def pull(run: "RobotRun", release: RenderedRelease) -> Result:
    supply = run.ctx.images
    assert supply is not None and run.t is not None, "called for a run with an image supply, once connected"
    pins = supply.pins_of(release)
    _say_moved(run, supply.moved())
    timeout = run.spec.command_timeout
    if supply.via(run.host) == "registry":
        return run.t.run(command(pins, None, timeout))
    link = getattr(run.t, "link", None)
    if link is None:
        raise ConnectError(run.host.name, "images.via ssh needs rosdeploy's own SSH connection to the robot")
    meter = Meter()
    limiters = (Limiter(supply.rate(run.host)), supply.fleet_limiter)
    stages = {pin.digest: supply.relay.stages_of(pin) for pin in pins}
    ok = False
    try:
        with Forward(link, supply.connect, limiters, meter, run.host.name) as port, _reporting(run, meter):
            result = run.t.run(command(pins, f"127.0.0.1:{port}", timeout, stages))
        ok = result.ok
        return result
    finally:    # also when the link drops: what arrived is part of the run's record
        run.steps.append(Step("images", meter.seconds, ok, detail=(
            f"via ssh from {supply.origin.describe}: {meter.sent} bytes sent in {meter.seconds:.1f} s "
            f"({human_bytes(meter.rate)}/s)")))


def _say_moved(run: "RobotRun", moved: dict[str, str]) -> None:
    pins = run.ctx.images.pins if run.ctx.images else {}
    for ref, now in sorted(moved.items()):
        pinned = pins[ref].digest
        message = (f"tag moved: {ref} now names {now[:19]}…; this run keeps deploying {pinned[:19]}…, "
                   "what it resolved at its start (the canary's bytes)")
        run.ctx.progress(run.host.name, message)
        run.steps.append(Step("tag moved", 0.0, detail=f"{ref}: pinned {pinned}, the registry now has {now}"))


@contextmanager
def _reporting(run: "RobotRun", meter: Meter, every: float = 1.0) -> Iterator[None]:
    """Bytes and rate on the robot's progress line while its images arrive."""
    done = threading.Event()

    def report() -> None:
        while not done.wait(every):
            if meter.sent:
                run.ctx.progress(run.host.name, f"pull: {human_bytes(meter.sent)} at {human_bytes(meter.rate)}/s")

    thread = threading.Thread(target=report, daemon=True, name=f"progress-{run.host.name}")
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def failure(result: Result, run: "RobotRun") -> str:
    """Why the pull failed, saying what to do; nothing changed on the robot."""
    supply = run.ctx.images
    missing = [line.split(" ", 2) for line in result.stdout.splitlines() if line.startswith("missing ")]
    detail = "; ".join(f"{m[1]}: {m[2].strip() if len(m) > 2 else ''}" for m in missing) or \
        (result.stdout + result.stderr).strip()[-400:]
    unreachable = any(word in detail.lower() for word in UNREACHABLE)
    if supply is not None and supply.via(run.host) == "registry" and unreachable:
        registry = split_ref(missing[0][1])[0] if missing else run.spec.registry
        return (f"preflight: the robot cannot reach the registry {registry or run.spec.registry} ({detail}); "
                "nothing changed. A robot without a route to the registry can take its images over SSH: "
                f"set `images.via: ssh` in the fleet file, or `rosdeploy_images_via: ssh` for it in the inventory")
    return f"pull failed, nothing changed: {detail}"


def digests(run: "RobotRun", release: RenderedRelease) -> dict[str, dict[str, str | None]]:
    """What the release manifest records of each image: the pinned digest and image id."""
    if run.ctx.images is None:
        return {}
    return {pin.ref: {"digest": pin.digest, "image_id": pin.image_id, "via": run.ctx.images.via(run.host)}
            for pin in run.ctx.images.pins_of(release)}
