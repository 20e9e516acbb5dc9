"""The plain values that flow between rosdeploy's stages.

    inventory/ -> Inventory/Host         fleet.py -> FleetSpec
    render.py (Host, FleetSpec) -> RenderedRelease
    deploy.py / rollout.py -> HostResult -> FleetResult

Everything here is frozen: a stage can hand its output to many threads (one per
robot) without anyone mutating it underneath the others.
"""
from __future__ import annotations

import functools
import hashlib
import hmac
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import Any, Mapping, TypeVar

K = TypeVar("K")
V = TypeVar("V")


def frozen_map(data: Mapping[K, V] | None = None) -> Mapping[K, V]:
    return MappingProxyType(dict(data or {}))


# --------------------------------------------------------------------- inventory

@dataclass(frozen=True)
class UdevDevice:
    """A stable /dev/robot/<symlink> name for a USB device, from vendor/product id."""

    symlink: str            # e.g. "robot/motor_controller" (relative to /dev)
    subsystem: str          # "tty", "video4linux", ...
    vendor: str             # idVendor, 4 hex digits
    product: str            # idProduct, 4 hex digits
    serial: str | None = None
    group: str | None = None   # e.g. "dialout"
    mode: str = "0660"


@dataclass(frozen=True)
class Host:
    """One robot, with every inventory var already merged by precedence."""

    name: str
    groups: tuple[str, ...]                 # every group it belongs to, ancestors included, "all" first
    vars: Mapping[str, Any]                 # merged vars (secrets included, see secret_values)
    address: str                            # ansible_host, or the name
    port: int = 22                          # ansible_port
    user: str | None = None                 # ansible_user (None: ssh config / local user)
    # the controller's side (key_file, key_file_var, source): not in the repr, which templates can print
    key_file: str | None = field(default=None, repr=False)   # ansible_ssh_private_key_file, absolute
    key_file_var: str = field(default="", repr=False)        # where key_file was set: "var (file:line)"
    ros_domain_id: int = 0
    devices: Mapping[str, str] = field(default_factory=frozen_map)   # logical name -> path on robot
    udev: tuple[UdevDevice, ...] = ()
    gpu: bool = False
    network: str = "default"                # robots sharing a network must not share a domain ID
    # every value that came from a vault file; not in repr: `{{ host|string }}` would write them all
    secret_values: frozenset[str] = field(default=frozenset(), repr=False)
    source: str = field(default="", repr=False)   # "file:line" where the host was declared


# ------------------------------------------------------------------------ fleet

@dataclass(frozen=True)
class Topic:
    name: str                   # "/joint_states"
    min_rate: float | None = None   # Hz; None: presence only


@dataclass(frozen=True)
class HealthCheck:
    test: tuple[str, ...]       # compose form: ("CMD", ...) or ("CMD-SHELL", "...")
    interval: str = "5s"
    timeout: str = "3s"
    retries: int = 3
    start_period: str = "10s"


@dataclass(frozen=True)
class Service:
    name: str
    image: str                  # repository without registry or tag, e.g. "demo/driver"
    tag: str                    # resolved tag (the release version unless the service pins one)
    command: tuple[str, ...] | None = None
    environment: Mapping[str, str] = field(default_factory=frozen_map)
    secret_env: Mapping[str, str] = field(default_factory=frozen_map)  # ENV name -> host var holding the secret
    devices: tuple[str, ...] = ()           # logical device names, resolved per robot
    volumes: tuple[str, ...] = ()           # bind mounts "/robot/path:/container/path:ro|rw"
    gpu: bool = False
    restart: str = "unless-stopped"
    memory: str | None = None               # mem_limit, e.g. "512m"
    cpus: float | None = None
    healthcheck: HealthCheck | None = None
    healthcheck_from_image: bool = False    # `healthcheck: image`: trust the image's own HEALTHCHECK
    depends_on: tuple[str, ...] = ()        # waits for service_healthy
    topics: tuple[Topic, ...] = ()          # expected ROS topics (health gate)
    user: str | None = None                 # container user; None: the image's own (should be non-root)
    privileged: bool = False
    allow_privileged: bool = False          # explicit opt-in the check rule wants
    profiles: tuple[str, ...] = ()
    extra: Mapping[str, Any] = field(default_factory=frozen_map)   # passed through to compose verbatim
    compose_interpolate: bool = False       # `$` in `extra` is compose interpolation (else written `$$`)
    digest: str | None = None               # `image: repo@sha256:…`: the bytes every robot gets under `tag`
    files: tuple[str, ...] = ()             # names of the fleet's `files:` this service mounts


@dataclass(frozen=True)
class RobotFile:
    """One entry of the fleet file's `files:`: a per-robot file mounted read-only into services."""

    name: str
    kind: str                   # "template" (Jinja2, sandboxed) | "copy" (as is) | "var" (an inventory var)
    source: str                 # a path under the fleet file's folder (may hold {{ }}), or the var's name
    target: str                 # absolute path in the container
    secret: bool = False        # may hold vault values: written 0600, masked in plan


@dataclass(frozen=True)
class HealthPolicy:
    timeout: float = 90.0       # seconds for the whole gate
    stable: float = 5.0         # seconds every container must stay up without restarting
    interval: float = 1.0       # seconds between container polls
    topic_window: float = 3.0   # seconds the ROS probe listens to measure rates
    # seconds a declared topic may take to get a publisher; past it the gate fails without
    # waiting for Docker's verdict (raise it for nodes that advertise late, e.g. lifecycle nodes)
    topics_within: float = 10.0
    probe_service: str | None = None   # where the ROS probe runs; None: first service with topics


@dataclass(frozen=True)
class RolloutPolicy:
    waves: tuple[int | str, ...] = ("100%",)   # ints are counts, "N%" are fractions of the targets
    max_fail: int | str = 0                     # failures tolerated per wave
    forks: int = 200
    order_by: str | None = None                 # an inventory group prefix, e.g. "site_" → one site at a time
    pause: float = 0.0                          # seconds between waves
    retry: float = 10.0                         # `apply --until`: first wait before a pending robot's next try
    retry_max: float = 300.0                    # ... doubling (with jitter) up to this
    count_busy: bool = False                    # busy robots count against max_fail


@dataclass(frozen=True)
class RollbackPolicy:
    auto: bool = True           # roll a robot back when its health gate fails
    fleet: bool = True          # when a rollout stops, roll back robots of earlier waves too
    keep_releases: int = 3
    guard: str = "revert"       # the robot's own end of a deploy its controller lost: revert | finish | off
    guard_margin: float = 30.0  # seconds past health.timeout before the guard acts


@dataclass(frozen=True)
class ImagePolicy:
    """How robots get their images (docs/images.md)."""

    via: str = "registry"               # "registry": the robot pulls; "ssh": through rosdeploy's SSH link
    max_rate: float | None = None       # bytes/s per robot over ssh (None: no cap)
    total_rate: float | None = None     # bytes/s for all robots together over ssh
    controller_registry: str | None = None   # the registry as the controller reaches it (None: `registry`)


@dataclass(frozen=True)
class FleetSpec:
    # path, inventory, templates, known_hosts, ssh_config: the controller's paths, not in the repr
    # (templates can print it; render._CONTROLLER_FIELDS)
    path: str = field(repr=False)                   # the fleet file
    project: str                    # compose project name on every robot
    inventory: str = field(repr=False)              # resolved path of the inventory
    registry: str                   # e.g. "registry.local:5000"
    version: str
    services: tuple[Service, ...]
    rmw: str = "fastdds"            # "fastdds" | "cyclonedds"
    network_mode: str = "host"      # "host" | "bridge"
    shm_size: str = "512m"
    log_max_size: str = "10m"
    log_max_file: int = 3
    log_rotate_every: float | None = 300.0   # seconds between runs of the ROS log rotation (None: off; rotation.py)
    templates: str | None = field(default=None, repr=False)   # a folder whose files override the built-in ones
    deploy_root: str = "~/rosdeploy"  # on the robot; "~" is the SSH user's home
    known_hosts: str | None = field(default=None, repr=False)  # None: ~/.ssh/known_hosts
    ssh_config: str | None = field(default=None, repr=False)   # None: ~/.ssh/config if present
    connect_timeout: float = 10.0
    command_timeout: float = 600.0
    ssh_persist: float = 60.0       # seconds read-only commands keep connections (0: off)
    min_free_disk_mb: int = 1024
    health: HealthPolicy = HealthPolicy()
    rollout: RolloutPolicy = RolloutPolicy()
    rollback: RollbackPolicy = RollbackPolicy()
    images: ImagePolicy = ImagePolicy()
    vars: Mapping[str, Any] = field(default_factory=frozen_map)  # extra template vars
    ready: Any = None               # ready.ReadyPolicy: the readiness gate (None: none)
    window: Any = None              # window.Window: the maintenance window (None: any time)
    files: tuple[RobotFile, ...] = ()   # per-robot files (`files:`), rendered into every release
    # line of every key path in the fleet file, so checks run after loading can say file:line
    lines: Mapping[tuple, int] = field(default_factory=frozen_map, repr=False, compare=False)
    # the file's warnings (errors.Problem): a number YAML 1.1 reads as octal; validate and check show them
    warnings: tuple[Any, ...] = field(default=(), repr=False, compare=False)

    def service(self, name: str) -> Service:
        return next(s for s in self.services if s.name == name)

    def image_ref(self, service: Service) -> str:
        return f"{self.registry}/{service.image}:{service.tag}" if self.registry else f"{service.image}:{service.tag}"


# ----------------------------------------------------------------------- render

_KEY_CONTEXT = b"rosdeploy: content address of secret content\0"


@functools.lru_cache(maxsize=64)     # a fleet's robots mostly share their vault files: one key for all
def secret_key(material: frozenset[str]) -> bytes:
    """The key of secret content's digests, from secret material only the controller holds (the
    robot's vault values): never written anywhere. Stable for the same material, and length-
    prefixed, so no two sets of texts give one key. Its limit: a guess must hold every vault value
    of the robot, but when the secret is the robot's only one, it is its own key. So a project
    keys with its vault passwords instead (project._address_key): then a rekey, not a changed
    vault value elsewhere, recreates the services that read a secret."""
    digest = hashlib.sha256(_KEY_CONTEXT)
    for text in sorted(material):
        data = text.encode("utf-8", "surrogatepass")
        digest.update(len(data).to_bytes(8, "big") + data)
    return digest.digest()


@dataclass(frozen=True)
class RenderedFile:
    name: str           # relative path inside the release dir, e.g. "compose.yml", ".env"
    content: str
    mode: int = 0o644   # .env (and anything holding a secret) is 0o600
    secret: bool = False


@dataclass(frozen=True)
class RenderedRelease:
    """Exactly what one robot receives. Deterministic: same inputs, same bytes, same digest."""

    host: str
    project: str
    version: str
    files: tuple[RenderedFile, ...]     # sorted by name
    images: tuple[str, ...]             # full refs to pull, sorted, e.g. "registry.local:5000/demo/driver:1.0.0"
    secret_values: frozenset[str] = field(default=frozenset(), repr=False)   # never printed
    # compose.yml as data when the built-in template wrote it (rosdeploy.compose_data), so the
    # checks need not parse it back; None for a user's own compose template. Not part of the digest.
    compose_data: Any = field(default=None, compare=False, repr=False)
    # the key of its secret files' digests (secret_key): the renderer's; None: from secret_values
    secret_key: bytes | None = field(default=None, compare=False, repr=False)

    @cached_property   # frozen: the files never change; 5,000 robots' tables and plans ask often
    def digest(self) -> str:
        """sha256 over names, modes and contents of every file: the release's identity. A file
        holding secrets (.env, a `secret: true` file) goes in as its HMAC under secret_key: the
        release id is a folder name on the robot and in every status, and a plain hash of the
        .env would let anyone who reads the other files test guesses of a short secret."""
        h = hashlib.sha256()
        for f in self.files:
            h.update(f"{f.name}\0{f.mode:o}\0".encode())
            data = f.content.encode("utf-8", "surrogatepass")
            h.update(hmac.new(self.secret_key or secret_key(self.secret_values), data, hashlib.sha256).digest()
                     if f.secret or (f.mode & 0o077) == 0 else data)
            h.update(b"\0")
        return h.hexdigest()

    @property
    def release_id(self) -> str:
        """Directory name of the release on the robot."""
        return f"{self.version}-{self.digest[:12]}"

    def file(self, name: str) -> RenderedFile:
        return next(f for f in self.files if f.name == name)
