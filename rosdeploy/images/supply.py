"""What one run's robots take their images from: the pins resolved once, the route per
robot, the rate caps, and where the controller fetches bytes (registry or bundle)."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
import socket
from typing import Callable, Iterable, Mapping, Sequence

from rosdeploy.errors import InputError, shown
from rosdeploy.images.forward import Limiter
from rosdeploy.images.refs import Layer, Pin, parse_rate, split_ref
from rosdeploy.images.registry import Manifest, RegistryError, Upstream, get_manifest
from rosdeploy.images.relay import Backend, RegistryBackend, Relay
from rosdeploy.model import FleetSpec, Host, RenderedRelease

VIA_VAR = "rosdeploy_images_via"
RATE_VAR = "rosdeploy_images_max_rate"
ROUTES = ("registry", "ssh")


@dataclass(frozen=True)
class Origin:
    """Where the controller's bytes come from: `describe` for people, `backend` for the relay
    robots pull through, `moved` (None for a bundle: it cannot change) to look a tag up again."""

    describe: str
    backend: Backend
    moved: Callable[[Pin], str | None] | None = None


class Supply:
    """Shared by every robot thread of a run; the pins never change once made."""

    def __init__(self, spec: FleetSpec, pins: Mapping[str, Pin], origin: Origin, resolve_seconds: float = 0.0,
                 via: str | None = None) -> None:
        self.spec = spec
        self.forced_via = via       # a bundle: every robot over ssh (there is no registry)
        self.pins = dict(pins)
        self.origin = origin
        self.resolve_seconds = resolve_seconds
        self.fleet_limiter = Limiter(spec.images.total_rate)
        self._lock = threading.Lock()
        self._checked = 0.0
        self._moved: dict[str, str] = {}
        self._relay: Relay | None = None

    @property
    def relay(self) -> Relay:
        """The registry robots reach through their forward; started by the first robot over ssh."""
        with self._lock:
            if self._relay is None:
                self._relay = Relay(self.origin.backend)
            return self._relay

    def connect(self) -> socket.socket:
        return socket.create_connection(self.relay.address, timeout=30)

    def via(self, host: Host) -> str:
        return self.forced_via or str(host.vars.get(VIA_VAR) or self.spec.images.via)

    def rate(self, host: Host) -> float | None:
        value = host.vars.get(RATE_VAR)
        return parse_rate(value) if value else self.spec.images.max_rate

    def pins_of(self, release: RenderedRelease) -> list[Pin]:
        return [self.pins[ref] for ref in release.images]

    def moved(self, every: float = 2.0) -> dict[str, str]:
        """ref -> the digest its tag names now, for pins whose tag moved since the run began.
        Looked up at most every `every` seconds, whichever robot asks (one look per wave)."""
        if self.origin.moved is None:
            return {}
        with self._lock:
            if time.monotonic() - self._checked >= every:
                for pin in self.pins.values():
                    now = None if pin.forced else self.origin.moved(pin)
                    if now:
                        self._moved[pin.ref] = now
                self._checked = time.monotonic()
            return dict(self._moved)

    def close(self) -> None:
        if self._relay is not None:
            self._relay.close()


def check_vars(hosts: Iterable[Host]) -> list[str]:
    """Problems with the per-robot image vars, each naming the robot and the var."""
    problems = []
    for host in hosts:
        via = host.vars.get(VIA_VAR)
        if via is not None and via not in ROUTES:
            problems.append(f"{host.source or host.name}: {host.name}: {VIA_VAR}: {shown(via)} is not a route: "
                            "use registry or ssh")
        rate = host.vars.get(RATE_VAR)
        if rate is not None:
            try:
                parse_rate(rate)
            except ValueError:
                problems.append(f"{host.source or host.name}: {host.name}: {RATE_VAR}: {shown(rate)} is not a rate "
                                "in bytes per second from 1kB/s up: write e.g. 2MB/s or 500kB/s")
    return problems


def forced_digests(spec: FleetSpec) -> dict[str, str]:
    """Normal name -> digest, for services the fleet file pins with `image@sha256:…`."""
    return {spec.image_ref(s): s.digest for s in spec.services if s.digest}


def controller_upstream(spec: FleetSpec) -> Upstream:
    return Upstream.parse(spec.images.controller_registry or spec.registry)


def pin_of(ref: str, manifest: Manifest, forced: bool = False) -> Pin:
    _, repository, _ = split_ref(ref)
    if manifest.is_index:
        return Pin(ref, repository, manifest.digest, None, forced=forced)
    doc = manifest.doc
    layers = tuple(Layer(item["digest"], int(item["size"])) for item in doc.get("layers", ()))
    return Pin(ref, repository, manifest.digest, doc["config"]["digest"], layers, forced)


def from_registry(spec: FleetSpec, releases: Sequence[RenderedRelease]) -> Supply:
    """Every tag the releases run, resolved once against the registry (one keep-alive connection)."""
    up = controller_upstream(spec)
    forced = forced_digests(spec)
    refs = sorted({ref for release in releases for ref in release.images})
    started = time.monotonic()
    conn = up.connection()
    try:
        pins = {ref: pin_of(ref, get_manifest(up, split_ref(ref)[1], forced.get(ref) or split_ref(ref)[2], conn),
                            forced=ref in forced) for ref in refs}
    except RegistryError as exc:
        raise InputError(f"resolving image digests: {exc}") from exc
    finally:
        conn.close()

    def moved(pin: Pin) -> str | None:
        try:
            now = get_manifest(up, pin.repository, split_ref(pin.ref)[2], method="HEAD").digest
        except RegistryError:
            return None     # cannot tell now; the pins still hold
        return now if now and now != pin.digest else None

    return Supply(spec, pins, Origin(f"registry {up}", RegistryBackend(up), moved), time.monotonic() - started)
