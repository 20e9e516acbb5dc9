"""Building the simulator's images once, and again only when their inputs change.

    debootstrap ─ robot-rootfs ─ robot                      (the robot containers)
    debootstrap ─ app-rootfs ─ ros-base ─ demo/driver:1.0.0 ... (pushed to the registry)

Every image carries the content hash of its build inputs as a label (files of its
context, build args, parent image); an image whose label matches is not built
again, and a demo image the registry already holds with the same digest is not
pushed again. That makes a warm `sim up` take seconds.
"""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import AbstractSet, Callable, Iterable

from rosdeploy.errors import SimError
from rosdeploy.sim import registry
from rosdeploy.sim.demo import DEMO_IMAGES, DemoImage
from rosdeploy.sim.model import LABEL, LABEL_INPUTS, REGISTRY_HOST, SimPaths, resolve_home
from rosdeploy.sim.proc import HOST_SETUP_HINT, Progress, docker, quiet, require_engine, run, run_logged
from rosdeploy.sim.rootfs import TRIM, RootfsSpec, build_rootfs_image, host_codename

IMAGES_DIR = Path(__file__).parent / "images"
RECIPE = "1"   # bump when the build steps change in a way the hashed files do not show

# sudo, logrotate and cron: what a Debian robot brings for rosdeploy's host changes (udev rules
# through `sudo -n`, the ROS log rotation schedule).
ROBOT_ROOTFS = RootfsSpec("robot-rootfs", ("openssh-server", "docker.io", "docker-compose", "iproute2",
                                           "procps", "ca-certificates", "tini", "sudo", "logrotate", "cron"))
APP_ROOTFS = RootfsSpec("app-rootfs", ("python3", "python3-venv"))

COMPOSE_PLUGIN_DIRS = ("~/.docker/cli-plugins", "/usr/local/lib/docker/cli-plugins",
                       "/usr/local/libexec/docker/cli-plugins", "/usr/lib/docker/cli-plugins",
                       "/usr/libexec/docker/cli-plugins")


@dataclass(frozen=True)
class SimImages:
    robot: str                    # local tag the robot containers run
    ros_base: str                 # local tag the demo images build on
    demo: tuple[str, ...]         # pushed refs, as the host names them (127.0.0.1:5000/demo/...)


@dataclass(frozen=True)
class _Build:
    """What one ensure step needs: where logs go and whom to tell."""

    paths: SimPaths
    workdir: Path
    suite: str
    progress: Progress


# ----------------------------------------------------------------- content hashing

def inputs_digest(parts: Iterable[tuple[str, bytes]]) -> str:
    """One sha256 over named inputs; order-independent, so it is stable across walks."""
    total = hashlib.sha256()
    for name, data in sorted(parts):
        total.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
    return total.hexdigest()


def tree_parts(root: Path, prefix: str = "") -> list[tuple[str, bytes]]:
    """(relative path + executable bit, content) of every file under root, caches excluded."""
    parts = []
    for path in sorted(root.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
            executable = "x" if path.stat().st_mode & 0o111 else "-"
            parts.append((f"{prefix}{path.relative_to(root)}:{executable}", path.read_bytes()))
    return parts


def value_parts(**values: str) -> list[tuple[str, bytes]]:
    return [(f"={key}", value.encode()) for key, value in values.items()]


def tag_for(name: str, digest: str) -> str:
    return f"rosdeploy-sim/{name}:{digest[:12]}"


# ----------------------------------------------------------------- docker queries

def image_inputs(ref: str) -> str | None:
    """The inputs label of a local image, or None when there is no such image."""
    result = docker("image", "inspect", "--format", f'{{{{index .Config.Labels "{LABEL_INPUTS}"}}}}', ref,
                    what=f"docker image inspect {ref}", check=False)
    return result.stdout.strip() if result.returncode == 0 else None


def repo_digests(ref: str) -> list[str]:
    result = docker("image", "inspect", "--format", "{{json .RepoDigests}}", ref,
                    what=f"docker image inspect {ref}")
    return json.loads(result.stdout or "[]") or []


def pushed(ref: str) -> bool:
    """True when the registry holds ref's tag with the digest of the local image."""
    name, tag = ref.removeprefix(f"{REGISTRY_HOST}/").rsplit(":", 1)
    remote = registry.manifest_digest(name, tag)
    return bool(remote) and f"{REGISTRY_HOST}/{name}@{remote}" in repo_digests(ref)


def find_compose_plugin() -> Path:
    """The host's Compose v2 CLI plugin, which robots get a copy of."""
    for folder in COMPOSE_PLUGIN_DIRS:
        candidate = Path(folder).expanduser() / "docker-compose"
        if candidate.is_file():
            version = run((str(candidate), "version"), what="docker compose version", check=False)
            if version.stdout.startswith("Docker Compose version v2"):
                return candidate
    raise SimError(f"no Docker Compose v2 plugin on this host; {HOST_SETUP_HINT}")


# ----------------------------------------------------------------- build steps

def _ensure(ref: str, digest: str, what: str, build: Callable[[], None], progress: Progress) -> str:
    if image_inputs(ref) == digest:
        progress(f"{what}: up to date ({ref})")
        return ref
    progress(f"{what}: building {ref}")
    started = time.monotonic()
    build()
    progress(f"{what}: built in {time.monotonic() - started:.0f} s")
    return ref


def _labels(digest: str) -> dict[str, str]:
    return {LABEL: "1", LABEL_INPUTS: digest}


def _docker_build(ctx: Path, ref: str, digest: str, args: dict[str, str], b: _Build, log_name: str) -> None:
    build_args = [arg for key, value in args.items() for arg in ("--build-arg", f"{key}={value}")]
    labels = [arg for key, value in _labels(digest).items() for arg in ("--label", f"{key}={value}")]
    # The classic builder: it needs no buildx plugin and builds FROM local images offline.
    run_logged(("docker", "build", "--network", "none", *build_args, *labels, "-t", ref, str(ctx)),
               what=f"docker build {ref}", log=b.paths.logs / f"build-{log_name}.log",
               progress=b.progress, env={"DOCKER_BUILDKIT": "0"})


def _remove_build_stages() -> None:
    # The classic builder keeps each multi-stage build's first stage as a dangling
    # image (here: wheels plus a venv, ~400 MB); only ours carry this label.
    stages = docker("images", "-q", "--filter", f"label={LABEL}.stage=build", what="docker images").stdout.split()
    if stages:
        docker("rmi", "-f", *sorted(set(stages)), what="removing build stages")


def _context(b: _Build, name: str) -> Path:
    """A fresh copy of images/<name> (without caches), to add generated files to."""
    ctx = Path(tempfile.mkdtemp(prefix=f"{name}-", dir=b.workdir))
    shutil.copytree(IMAGES_DIR / name, ctx, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"),
                    dirs_exist_ok=True)
    return ctx


def ensure_rootfs(spec: RootfsSpec, b: _Build) -> str:
    arch = run(("dpkg", "--print-architecture"), what="dpkg --print-architecture").stdout.strip()
    digest = inputs_digest(value_parts(recipe=RECIPE, suite=b.suite, arch=arch,
                                       packages=",".join(spec.packages), trim=",".join(TRIM)))
    ref = tag_for(spec.name, digest)
    return _ensure(ref, digest, spec.name, lambda: build_rootfs_image(
        spec, b.suite, ref, _labels(digest), b.workdir, b.paths.logs / f"debootstrap-{spec.name}.log",
        b.progress), b.progress)


def ensure_robot_image(b: _Build) -> str:
    rootfs = ensure_rootfs(ROBOT_ROOTFS, b)
    compose = find_compose_plugin()
    digest = inputs_digest(tree_parts(IMAGES_DIR / "robot") + [("docker-compose", compose.read_bytes())]
                           + value_parts(ROOTFS=rootfs))

    def build() -> None:
        ctx = _context(b, "robot")
        shutil.copy2(compose, ctx / "docker-compose")
        (ctx / "docker-compose").chmod(0o755)
        _docker_build(ctx, ref, digest, {"ROOTFS": rootfs}, b, "robot")

    ref = tag_for("robot", digest)
    return _ensure(ref, digest, "robot image", build, b.progress)


def ensure_ros_base(b: _Build) -> str:
    if sys.version_info[:2] != (3, 11):
        raise SimError("the ROS 2 wheels are downloaded for Debian 12's Python 3.11; "
                       f"run rosdeploy with Python 3.11 (this is {sys.version.split()[0]})")
    rootfs = ensure_rootfs(APP_ROOTFS, b)
    digest = inputs_digest(tree_parts(IMAGES_DIR / "ros-base") + value_parts(ROOTFS=rootfs))

    def build() -> None:
        ctx = _context(b, "ros-base")
        run_logged((sys.executable, "-m", "pip", "wheel", "--quiet", "-w", str(ctx / "wheels"),
                    "-r", str(ctx / "requirements.txt")),
                   what="downloading ROS 2 wheels", log=b.paths.logs / "wheels.log", progress=b.progress)
        _docker_build(ctx, ref, digest, {"ROOTFS": rootfs}, b, "ros-base")
        _remove_build_stages()

    ref = tag_for("ros-base", digest)
    return _ensure(ref, digest, "ROS 2 base image", build, b.progress)


def ensure_demo_image(image: DemoImage, base: str, b: _Build) -> str:
    ref = f"{REGISTRY_HOST}/{image.repository}:{image.tag}"
    digest = inputs_digest(tree_parts(IMAGES_DIR / "demo") + value_parts(BASE=base, **image.build_args()))
    log_name = f"{image.node}-{image.tag}"
    _ensure(ref, digest, f"{image.repository}:{image.tag}",
            lambda: _docker_build(_context(b, "demo"), ref, digest, {"BASE": base, **image.build_args()},
                                  b, log_name), b.progress)
    if not pushed(ref):
        b.progress(f"pushing {ref}")
        run_logged(("docker", "push", ref), what=f"docker push {ref}", log=b.paths.logs / f"push-{log_name}.log",
                   progress=b.progress)
    return ref


def _app_chain(b: _Build) -> tuple[str, tuple[str, ...]]:
    base = ensure_ros_base(b)
    return base, tuple(ensure_demo_image(image, base, b) for image in DEMO_IMAGES)


def ensure_images(progress: Progress = quiet, home: Path | str | None = None) -> SimImages:
    """Build and push whatever is missing or out of date; the registry must answer."""
    require_engine()
    if not registry.answers():
        raise SimError(f"no registry answers on {REGISTRY_HOST}; `rosdeploy sim up` starts one")
    paths = SimPaths(resolve_home(home))
    with tempfile.TemporaryDirectory(prefix="rosdeploy-sim-build-") as tmp:
        b = _Build(paths=paths, workdir=Path(tmp), suite=host_codename(), progress=progress)
        # The two chains share nothing until the end: build them side by side
        # (each debootstrap is mostly waiting on downloads and dpkg).
        with ThreadPoolExecutor(max_workers=2, thread_name_prefix="sim-build") as pool:
            robot = pool.submit(ensure_robot_image, b)
            app = pool.submit(_app_chain, b)
            base, demo = app.result()
            images = SimImages(robot=robot.result(), ros_base=base, demo=demo)
    prune_superseded(images)
    return images


def prune_superseded(current: SimImages) -> None:
    """Remove the simulator's images that older build inputs made (never the current
    ones or their parents; an image a robot container still runs stays too)."""
    remove_images(keep={_image_id(ref) for ref in (current.robot, current.ros_base, *current.demo)})


def remove_images(keep: AbstractSet[str] = frozenset()) -> list[str]:
    """Remove every image the simulator built except `keep` (ids); return the ids left,
    i.e. kept ones and those still in use by a container."""
    removed = True
    while removed:      # a parent can go only after its children: repeat until nothing moves
        listing = set(docker("images", "--filter", f"label={LABEL}", "--format", "{{.ID}}", "--no-trunc",
                             what="docker images").stdout.split())
        # Without -f: images in use and parents of kept images refuse, which is what we want.
        removed = any([docker("rmi", image_id, what="removing an image", check=False).returncode == 0
                       for image_id in sorted(listing - keep)])
    return sorted(listing)


def _image_id(ref: str) -> str:
    return docker("image", "inspect", "--format", "{{.Id}}", ref, what=f"docker image inspect {ref}").stdout.strip()
