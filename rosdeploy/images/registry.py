"""The controller's side of a registry: resolve a tag to its digest, read manifests and blobs.

Registry HTTP API v2, anonymous (a registry that asks for a token is reported, not
handled: see docs/images.md). The controller reaches the registry at
`images.controller_registry` (default: the fleet's `registry`), which can differ from the
name robots use (`registry.local:5000` on the robots, `127.0.0.1:5000` on the controller).
"""
from __future__ import annotations

import hashlib
import http.client
import json
import socket
from dataclasses import dataclass
from typing import Iterator

from rosdeploy.errors import RosdeployError

MANIFEST_TYPES = (
    "application/vnd.docker.distribution.manifest.v2+json",
    "application/vnd.docker.distribution.manifest.list.v2+json",
    "application/vnd.oci.image.manifest.v1+json",
    "application/vnd.oci.image.index.v1+json",
)
INDEX_TYPES = (MANIFEST_TYPES[1], MANIFEST_TYPES[3])


class RegistryError(RosdeployError):
    """The controller could not read what it needs from the registry."""


@dataclass(frozen=True)
class Upstream:
    """Where the controller reaches a registry: host, port, TLS or not."""

    host: str
    port: int
    tls: bool

    @classmethod
    def parse(cls, address: str) -> "Upstream":
        """`https://r.example`, `http://127.0.0.1:5000`, or `host:port` (TLS unless it is this
        machine, as Docker itself assumes)."""
        scheme, sep, rest = address.partition("://")
        if not sep:
            scheme, rest = "", address
        rest = rest.split("/", 1)[0]
        host, _, port = rest.rpartition(":") if ":" in rest else (rest, "", "")
        local = host in ("localhost", "::1") or host.startswith("127.")
        tls = scheme == "https" or (not scheme and not local)
        return cls(host, int(port) if port else (443 if tls else 80), tls)

    def __str__(self) -> str:
        return f"{'https' if self.tls else 'http'}://{self.host}:{self.port}"

    def connection(self, timeout: float = 30.0) -> http.client.HTTPConnection:
        cls = http.client.HTTPSConnection if self.tls else http.client.HTTPConnection
        return cls(self.host, self.port, timeout=timeout)

    def socket(self, timeout: float = 30.0) -> socket.socket:
        """A plain TCP connection, for the forwarder (TLS, if any, runs end to end through it)."""
        return socket.create_connection((self.host, self.port), timeout=timeout)


@dataclass(frozen=True)
class Manifest:
    digest: str
    media_type: str
    body: bytes

    @property
    def doc(self) -> dict:
        return json.loads(self.body)

    @property
    def is_index(self) -> bool:
        return self.media_type in INDEX_TYPES or "manifests" in self.doc


def get_manifest(up: Upstream, repository: str, reference: str, conn: http.client.HTTPConnection | None = None,
                 method: str = "GET") -> Manifest:
    """The manifest `reference` (tag or digest) names; its digest verified against its bytes."""
    own = conn is None
    conn = conn or up.connection()
    try:
        conn.request(method, f"/v2/{repository}/manifests/{reference}", headers={"Accept": ", ".join(MANIFEST_TYPES)})
        response = conn.getresponse()
        body = response.read()
    except (OSError, http.client.HTTPException) as exc:
        raise RegistryError(f"registry {up} does not answer ({exc}): fix `images.controller_registry` "
                            "(the registry as this machine reaches it)") from exc
    finally:
        if own:
            conn.close()
    if response.status == 401:
        raise RegistryError(f"registry {up} wants credentials for {repository}; rosdeploy reads registries "
                            "anonymously (see docs/images.md)")
    if response.status != 200:
        raise RegistryError(f"{repository}:{reference}: the registry {up} answers {response.status} "
                            "(is it pushed?)")
    header = response.getheader("Docker-Content-Digest") or ""
    if method == "HEAD":
        return Manifest(header, response.getheader("Content-Type") or "", b"")
    digest = "sha256:" + hashlib.sha256(body).hexdigest()
    if header and header != digest or reference.startswith("sha256:") and reference != digest:
        raise RegistryError(f"{repository}:{reference}: the manifest's bytes do not match its digest")
    return Manifest(digest, response.getheader("Content-Type") or "", body)


def blob_chunks(up: Upstream, repository: str, digest: str, chunk: int = 1 << 20) -> Iterator[bytes]:
    """A blob's bytes, streamed; the caller checks the digest over them."""
    conn = up.connection(timeout=120)
    try:
        conn.request("GET", f"/v2/{repository}/blobs/{digest}")
        response = conn.getresponse()
        while response.status in (301, 302, 307):   # a storage redirect: follow it once
            location = response.getheader("Location") or ""
            response.read()
            conn.close()
            conn, path = _follow(location)
            conn.request("GET", path)
            response = conn.getresponse()
        if response.status != 200:
            raise RegistryError(f"{repository}@{digest}: the registry {up} answers {response.status}")
        while data := response.read(chunk):
            yield data
    finally:
        conn.close()


def _follow(location: str) -> tuple[http.client.HTTPConnection, str]:
    scheme, _, rest = location.partition("://")
    hostport, _, path = rest.partition("/")
    up = Upstream.parse(f"{scheme}://{hostport}")
    return up.connection(timeout=120), "/" + path
