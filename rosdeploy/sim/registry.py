"""The local image registry the simulated robots pull from.

Debian's distribution/registry runs as a host process (no registry image can be
pulled here: there is no Docker Hub). It listens on all interfaces because robots
reach it through the docker0 gateway (`registry.local` inside a robot); the host
pushes to 127.0.0.1:5000, which Docker allows without TLS.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import TypeGuard

from rosdeploy.errors import SimError
from rosdeploy.sim.model import REGISTRY_HOST, SimPaths
from rosdeploy.sim.proc import HOST_SETUP_HINT

_MANIFEST_TYPES = ", ".join((
    "application/vnd.docker.distribution.manifest.v2+json",
    "application/vnd.docker.distribution.manifest.list.v2+json",
    "application/vnd.oci.image.manifest.v1+json",
    "application/vnd.oci.image.index.v1+json",
))


def answers(address: str = REGISTRY_HOST, timeout: float = 2.0) -> bool:
    try:
        with urllib.request.urlopen(f"http://{address}/v2/", timeout=timeout) as response:
            return response.status == 200
    except urllib.error.HTTPError as exc:
        return exc.code == 401          # a registry with auth still is a registry
    except OSError:
        return False


def manifest_digest(repository: str, tag: str, address: str = REGISTRY_HOST) -> str | None:
    """The digest the registry holds for repository:tag, or None when it has none."""
    request = urllib.request.Request(f"http://{address}/v2/{repository}/manifests/{tag}",
                                     method="HEAD", headers={"Accept": _MANIFEST_TYPES})
    try:
        with urllib.request.urlopen(request, timeout=5) as response:
            return response.headers.get("Docker-Content-Digest")
    except OSError:
        return None


def config_text(paths: SimPaths) -> str:
    # The Debian default config wants htpasswd auth; the sim needs none.
    return (
        "version: 0.1\n"
        "log: {level: warn, accesslog: {disabled: true}}\n"
        f"storage: {{filesystem: {{rootdirectory: {paths.registry_data}}}, delete: {{enabled: true}}}}\n"
        "http: {addr: 0.0.0.0:5000}\n"
    )


def start(paths: SimPaths, timeout: float = 20.0) -> int:
    """Start a registry process serving paths.registry_data; return its pid once it answers."""
    config = paths.home / "registry.yml"
    config.write_text(config_text(paths))
    paths.registry_data.mkdir(parents=True, exist_ok=True)
    paths.logs.mkdir(parents=True, exist_ok=True)
    with (paths.logs / "registry.log").open("a") as log:
        try:
            # A session of its own: the registry outlives this process (sim up returns).
            proc = subprocess.Popen(["docker-registry", "serve", str(config)], stdout=log,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True)
        except FileNotFoundError as exc:
            raise SimError(f"docker-registry is not installed; {HOST_SETUP_HINT}") from exc
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if answers():
            return proc.pid
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    stop(proc.pid)
    raise SimError(f"the registry did not answer on {REGISTRY_HOST} (is port 5000 taken?); "
                   f"see {paths.logs / 'registry.log'}")


def is_ours(pid: int | None, paths: SimPaths) -> TypeGuard[int]:
    """True when pid still is the registry this state dir started (pids get reused)."""
    if not pid:
        return False
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"docker-registry" in cmdline[0] and str(paths.home / "registry.yml").encode() in cmdline


def stop(pid: int, timeout: float = 10.0) -> None:
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and _alive(pid):
        time.sleep(0.1)
    if _alive(pid):
        os.kill(pid, signal.SIGKILL)


def _alive(pid: int) -> bool:
    try:
        # Reap it if it is our own child (started in this process), so it is not a zombie.
        if os.waitpid(pid, os.WNOHANG)[0] == pid:
            return False
    except ChildProcessError:
        pass
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
