"""Air-gapped sites: one file with a release's images, and a registry served from it.

A bundle is an uncompressed tar holding an OCI image layout (`oci-layout`, `index.json`,
`blobs/sha256/…`: manifests, configs and layers exactly as the registry stores them)
plus `rosdeploy-bundle.json` (the pins: normal name -> digest, image id). Layers are
already compressed, so the tar is not; and uncompressed, the controller serves a blob
straight from its offset in the file, with no unpacking.

`BundleBackend` gives the relay (relay.py: the read-only registry API v2 robots pull from,
through the same SSH forward as from a real registry) its manifests and blobs.
"""
from __future__ import annotations

import hashlib
import io
import json
import stat
import tarfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

from rosdeploy.errors import InputError
from rosdeploy.images.refs import Layer, Pin, split_ref
from rosdeploy.images.registry import RegistryError, Upstream, blob_chunks, get_manifest
from rosdeploy.images.supply import Origin, Supply, controller_upstream, from_registry
from rosdeploy.model import FleetSpec, RenderedRelease

META = "rosdeploy-bundle.json"
REF_ANNOTATION = "org.opencontainers.image.ref.name"
Say = Callable[[str], None]


# ----------------------------------------------------------------- writing

def write(spec: FleetSpec, releases: Sequence[RenderedRelease], out: Path, say: Say = lambda m: None) -> Supply:
    """Resolve the releases' images against the registry and write them to `out`; return the pins."""
    supply = from_registry(spec, releases)
    up = controller_upstream(spec)
    part = out.with_name(out.name + ".part")
    try:
        with tarfile.open(part, "w", format=tarfile.PAX_FORMAT) as tar:
            _add_bytes(tar, "oci-layout", b'{"imageLayoutVersion": "1.0.0"}\n')
            written: set[str] = set()
            index = [_add_image(tar, up, pin, written, say) for pin in supply.pins.values()]
            _add_bytes(tar, "index.json", _json({"schemaVersion": 2, "manifests": index}))
            _add_bytes(tar, META, _json({"format": 1, "project": spec.project, "version": spec.version,
                                         "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                                         "pins": {p.ref: _pin_doc(p) for p in supply.pins.values()}}))
        part.replace(out)
    except (RegistryError, OSError) as exc:
        part.unlink(missing_ok=True)
        raise InputError(f"bundle {out}: {exc}") from exc
    return supply


def _add_image(tar: tarfile.TarFile, up: Upstream, pin: Pin, written: set[str], say: Say) -> dict:
    manifest = get_manifest(up, pin.repository, pin.digest)
    _add_blob(tar, manifest.digest, manifest.body, written)
    for child in manifest.doc.get("manifests", ()):        # an index: every platform it names
        _add_image(tar, up, Pin(pin.ref, pin.repository, child["digest"], None), written, say)
    for desc in ([manifest.doc["config"]] if "config" in manifest.doc else []) + manifest.doc.get("layers", []):
        if desc["digest"] in written:
            continue
        say(f"{pin.repository}: {desc['digest'][:19]}… ({desc['size']} bytes)")
        _add_stream(tar, desc["digest"], int(desc["size"]), blob_chunks(up, pin.repository, desc["digest"]))
        written.add(desc["digest"])
    return {"mediaType": manifest.media_type or manifest.doc.get("mediaType", ""), "digest": manifest.digest,
            "size": len(manifest.body), "annotations": {REF_ANNOTATION: pin.ref}}


def _pin_doc(pin: Pin) -> dict:
    return {"repository": pin.repository, "digest": pin.digest, "image_id": pin.image_id,
            "layers": [[layer.digest, layer.size] for layer in pin.layers], "forced": pin.forced}


def _json(doc: dict) -> bytes:
    return (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode()


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size, info.mode, info.mtime = len(data), 0o644, int(time.time())
    tar.addfile(info, io.BytesIO(data))


def _add_blob(tar: tarfile.TarFile, digest: str, data: bytes, written: set[str]) -> None:
    if digest not in written:
        _add_stream(tar, digest, len(data), iter([data]))
        written.add(digest)


def _add_stream(tar: tarfile.TarFile, digest: str, size: int, chunks: Iterator[bytes]) -> None:
    info = tarfile.TarInfo(blob_path(digest))
    info.size, info.mode, info.mtime = size, 0o644, int(time.time())
    reader = _Checked(chunks, digest, size)
    tar.addfile(info, reader)
    reader.finish()


class _Checked(io.RawIOBase):
    """Chunks as a file, hashed on the way: a blob whose bytes are not its digest never lands."""

    def __init__(self, chunks: Iterator[bytes], digest: str, size: int) -> None:
        self.chunks, self.digest, self.size = chunks, digest, size
        self.hash, self.count, self.buf = hashlib.sha256(), 0, b""

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        while (n < 0 or len(self.buf) < n) and (chunk := next(self.chunks, None)) is not None:
            self.buf += chunk
        data, self.buf = (self.buf, b"") if n < 0 else (self.buf[:n], self.buf[n:])
        self.hash.update(data)
        self.count += len(data)
        return data

    def finish(self) -> None:
        if self.count != self.size or "sha256:" + self.hash.hexdigest() != self.digest:
            raise RegistryError(f"blob {self.digest}: the registry sent {self.count} bytes that do not match "
                                "its digest")


def blob_path(digest: str) -> str:
    algorithm, _, hexdigest = digest.partition(":")
    return f"blobs/{algorithm}/{hexdigest}"


# ----------------------------------------------------------------- reading

@dataclass(frozen=True)
class Bundle:
    path: Path
    members: Mapping[str, tuple[int, int]]      # name in the tar -> (offset of data, size)
    meta: dict

    @classmethod
    def open(cls, path: Path) -> "Bundle":
        _regular(path)
        try:
            with tarfile.open(path, "r:") as tar:
                members = {m.name: (m.offset_data, m.size) for m in tar.getmembers() if m.isfile()}
                meta = json.loads(tar.extractfile(META).read())     # type: ignore[union-attr]
        except (OSError, tarfile.TarError, KeyError, ValueError) as exc:
            raise InputError(f"{path}: not a rosdeploy bundle ({exc}); write one with `rosdeploy bundle`") from exc
        return cls(path, members, meta)

    def pins(self) -> dict[str, Pin]:
        return {ref: Pin(ref, d["repository"], d["digest"], d.get("image_id"),
                         tuple(Layer(*layer) for layer in d.get("layers", ())), d.get("forced", False))
                for ref, d in self.meta["pins"].items()}

    def has(self, digest: str) -> bool:
        return blob_path(digest) in self.members

    def read(self, digest: str) -> bytes:
        offset, size = self.members[blob_path(digest)]
        with self.path.open("rb") as f:
            f.seek(offset)
            return f.read(size)

    def verify(self) -> list[str]:
        """Blobs whose bytes are not their digest (a damaged copy of the file)."""
        bad = []
        with self.path.open("rb") as f:
            for name, (offset, size) in self.members.items():
                if not name.startswith("blobs/sha256/"):
                    continue
                f.seek(offset)
                h, left = hashlib.sha256(), size
                while left:
                    chunk = f.read(min(left, 1 << 20))
                    if not chunk:
                        break
                    h.update(chunk)
                    left -= len(chunk)
                if h.hexdigest() != name.rsplit("/", 1)[-1]:
                    bad.append(name)
        return bad


def from_bundle(spec: FleetSpec, releases: Sequence[RenderedRelease], path: Path) -> Supply:
    """Pins from the bundle (checked whole), and a registry served from it on 127.0.0.1."""
    started = time.monotonic()
    bundle = Bundle.open(path)
    damaged = bundle.verify()
    if damaged:
        raise InputError(f"{path}: {len(damaged)} blob(s) do not match their digest (a damaged copy): "
                         f"{', '.join(damaged[:3])}; copy the bundle again")
    pins = bundle.pins()
    missing = sorted({ref for r in releases for ref in r.images} - set(pins))
    if missing:
        raise InputError(f"{path} holds no {', '.join(missing)} (it has {', '.join(sorted(pins)) or 'nothing'}): "
                         f"write a bundle of this version with `rosdeploy bundle FLEET --version {spec.version}`")
    origin = Origin(f"bundle {path.name}", BundleBackend(bundle, pins))
    return Supply(spec, pins, origin, time.monotonic() - started, via="ssh")


def _regular(path: Path) -> None:
    """A FIFO or a device would be read forever (tarfile waits for a writer that never comes)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return      # missing, unreadable: tarfile.open says so in the message of its own
    if not stat.S_ISREG(mode):
        raise InputError(f"{path}: not a regular file; give the file `rosdeploy bundle` wrote")


# ----------------------------------------------------------------- serving

class BundleBackend:
    """The relay's bytes from a bundle: a blob is a slice of the tar, read in place."""

    def __init__(self, bundle: Bundle, pins: Mapping[str, Pin]) -> None:
        self.bundle = bundle
        self.tags = {(pin.repository, split_ref(pin.ref)[2]): pin.digest for pin in pins.values()}

    def manifest(self, name: str, ref: str) -> tuple[bytes, str, str] | None:
        digest = ref if ref.startswith("sha256:") else self.tags.get((name, ref))
        if not digest or not self.bundle.has(digest):
            return None
        data = self.bundle.read(digest)
        return data, json.loads(data).get("mediaType", "application/vnd.oci.image.manifest.v1+json"), digest

    def blob(self, name: str, digest: str, start: int) -> tuple[int, Iterator[bytes]] | None:
        if not self.bundle.has(digest):
            return None
        offset, size = self.bundle.members[blob_path(digest)]
        start = start if 0 < start < size else 0
        return size, _slice(self.bundle.path, offset + start, size - start)


def _slice(path: Path, offset: int, size: int) -> Iterator[bytes]:
    with path.open("rb") as f:
        f.seek(offset)
        while size > 0:
            chunk = f.read(min(size, 1 << 16))
            if not chunk:
                break
            yield chunk
            size -= len(chunk)
