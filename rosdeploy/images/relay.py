"""The registry robots see through the forward: a small read-only registry API v2 server
on the controller's 127.0.0.1, backed by the real registry or by a bundle.

Why not pipe the forward straight to the registry: a `docker pull` that fails halfway
throws away every layer it already had (dockerd releases a failed pull's layers), so a
link that drops at 90 % would send it all again. The relay adds *stage* images: for an
image of layers L1…Ln it serves synthetic manifests of L1…Lk (a minimal config whose
rootfs is those layers' diff ids, labelled io.rosdeploy.stage). The robot pulls the
stages one after the other, then the image itself: each stage that arrives is an image
holding its layers, so a later pull says "Already exists" for them and sends only what
is missing. Stage images are removed once the image holds its pin.

Served: GET/HEAD /v2/, /v2/<name>/manifests/<tag|digest>, /v2/<name>/blobs/<digest>
(with `Range: bytes=N-`).
"""
from __future__ import annotations

import hashlib
import http.client
import json
import re
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Iterator, Protocol

from rosdeploy.images.refs import Pin
from rosdeploy.images.registry import RegistryError, Upstream, get_manifest

STAGE_LABEL = "io.rosdeploy.stage"
STAGE_MIN = 1_000_000        # a layer smaller than this gets no stage of its own: re-sending it is cheap
_MANIFEST_PATH = re.compile(r"/v2/(?P<name>.+)/manifests/(?P<ref>[^/]+)")
_BLOB_PATH = re.compile(r"/v2/(?P<name>.+)/blobs/(?P<digest>sha256:[0-9a-f]{64})")
MANIFEST_V2 = "application/vnd.docker.distribution.manifest.v2+json"
CONFIG_V1 = "application/vnd.docker.container.image.v1+json"


class Backend(Protocol):
    def manifest(self, name: str, ref: str) -> tuple[bytes, str, str] | None:
        """(body, media type, digest), or None when there is no such manifest."""

    def blob(self, name: str, digest: str, start: int) -> tuple[int, Iterator[bytes]] | None:
        """(whole size, chunks from `start`), or None when there is no such blob."""


class RegistryBackend:
    def __init__(self, up: Upstream) -> None:
        self.up = up

    def manifest(self, name: str, ref: str) -> tuple[bytes, str, str] | None:
        try:
            m = get_manifest(self.up, name, ref)
        except RegistryError:
            return None
        return m.body, m.media_type or json.loads(m.body).get("mediaType", MANIFEST_V2), m.digest

    def blob(self, name: str, digest: str, start: int) -> tuple[int, Iterator[bytes]] | None:
        conn = self.up.connection(timeout=120)
        conn.request("GET", f"/v2/{name}/blobs/{digest}", headers={"Range": f"bytes={start}-"} if start else {})
        response = conn.getresponse()
        if response.status not in (200, 206):
            conn.close()
            return None
        length = int(response.getheader("Content-Length") or 0)
        if response.status == 200:
            start = 0       # the registry ignored the range: send it whole
        return start + length, _chunks(response, conn)


def _chunks(response: http.client.HTTPResponse, conn: http.client.HTTPConnection) -> Iterator[bytes]:
    try:
        while data := response.read(1 << 16):
            yield data
    finally:
        conn.close()


class Relay:
    """The server, in a thread; synthetic stage manifests and configs live in `extra`."""

    def __init__(self, backend: Backend) -> None:
        self.backend = backend
        self.extra: dict[str, tuple[bytes, str]] = {}
        self.stages: dict[str, tuple[str, ...]] = {}     # pin digest -> its stage manifests' digests
        self._lock = threading.Lock()
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(self))
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, daemon=True, name="image-relay").start()

    @property
    def address(self) -> tuple[str, int]:
        return self.server.server_address[:2]     # type: ignore[return-value]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    def add(self, body: bytes, media_type: str) -> str:
        digest = "sha256:" + hashlib.sha256(body).hexdigest()
        self.extra[digest] = (body, media_type)
        return digest

    def stages_of(self, pin: Pin) -> tuple[str, ...]:
        """Digests of the pin's stage manifests, made once per run (first robot that needs them)."""
        with self._lock:
            if pin.digest not in self.stages:
                self.stages[pin.digest] = self._make_stages(pin)
            return self.stages[pin.digest]

    def _make_stages(self, pin: Pin) -> tuple[str, ...]:
        found = self.backend.manifest(pin.repository, pin.digest)
        if found is None or pin.image_id is None:
            return ()
        manifest = json.loads(found[0])
        config = self._read(pin.repository, manifest["config"]["digest"])
        if config is None:
            return ()
        base = json.loads(config)
        diff_ids = base["rootfs"]["diff_ids"]
        layers = manifest["layers"]
        cuts = [k for k in range(1, len(layers)) if layers[k - 1]["size"] >= STAGE_MIN]
        return tuple(self._stage(base, layers, diff_ids, k) for k in cuts)

    def _stage(self, base: dict, layers: list, diff_ids: list, k: int) -> str:
        config = json.dumps({"architecture": base.get("architecture", "amd64"), "os": base.get("os", "linux"),
                             "config": {"Labels": {STAGE_LABEL: "1"}},
                             "rootfs": {"type": "layers", "diff_ids": diff_ids[:k]}}, sort_keys=True).encode()
        digest = self.add(config, CONFIG_V1)
        manifest = json.dumps({"schemaVersion": 2, "mediaType": MANIFEST_V2,
                               "config": {"mediaType": CONFIG_V1, "size": len(config), "digest": digest},
                               "layers": layers[:k]}, indent=3).encode()
        return self.add(manifest, MANIFEST_V2)

    def _read(self, name: str, digest: str) -> bytes | None:
        found = self.backend.blob(name, digest, 0)
        return b"".join(found[1]) if found else None


def _handler(relay: Relay) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args: object) -> None:
            pass        # nothing below cli/ prints

        def do_HEAD(self) -> None:
            self.do_GET(body=False)

        def do_GET(self, body: bool = True) -> None:
            path = self.path.split("?", 1)[0]
            if path in ("/v2", "/v2/"):
                return self._send(200, b"{}", "application/json", body=body)
            if match := _MANIFEST_PATH.fullmatch(path):
                extra = relay.extra.get(match["ref"])
                manifest = (*extra, match["ref"]) if extra else relay.backend.manifest(match["name"], match["ref"])
                if manifest:
                    return self._send(200, manifest[0], manifest[1], manifest[2], body)
                return self._send(404, b'{"errors":[{"code":"MANIFEST_UNKNOWN"}]}', "application/json", body=body)
            if match := _BLOB_PATH.fullmatch(path):
                if match["digest"] in relay.extra:
                    return self._send(200, relay.extra[match["digest"]][0], "application/octet-stream",
                                      match["digest"], body)
                start = _range_start(self.headers.get("Range"))
                blob = relay.backend.blob(match["name"], match["digest"], start)
                if blob:
                    return self._blob(match["digest"], start, *blob, body=body)
            return self._send(404, b'{"errors":[{"code":"BLOB_UNKNOWN"}]}', "application/json", body=body)

        def _send(self, code: int, data: bytes, kind: str, digest: str = "", body: bool = True) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Docker-Distribution-API-Version", "registry/2.0")
            if digest:
                self.send_header("Docker-Content-Digest", digest)
            self.end_headers()
            if body:
                self.wfile.write(data)

        def _blob(self, digest: str, start: int, size: int, chunks: Iterator[bytes], body: bool) -> None:
            self.send_response(206 if start else 200)
            self.send_header("Content-Type", "application/octet-stream")
            self.send_header("Content-Length", str(size - start))
            self.send_header("Docker-Content-Digest", digest)
            if start:
                self.send_header("Content-Range", f"bytes {start}-{size - 1}/{size}")
            self.end_headers()
            for data in chunks:
                if not body:
                    break
                self.wfile.write(data)
            if hasattr(chunks, "close"):
                chunks.close()

    return Handler


def _range_start(header: str | None) -> int:
    match = re.fullmatch(r"bytes=(\d+)-\d*", header or "")
    return int(match[1]) if match else 0
