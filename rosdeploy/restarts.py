"""Restart only what changed: per-service hashes and the content-addressed file store.

Compose recreates a container when its service's configuration hash changes. Two
things used to change it on every release: the `io.rosdeploy.version` label, and
bind mounts of files inside the release directory (`./fastdds.xml` resolves to
releases/<id>/fastdds.xml, a new path each release). So:

- each service carries `io.rosdeploy.hash`, a digest of what it runs (image, config,
  environment, secret values it reads, mounted files' contents), instead of the version;
- a file a container mounts lives at store/<content digest>/<name> under the project
  dir: the same path while its content is the same. A release holds its store files
  too (releases/<id>/store/...), and `link_store` hard-links them into the project's
  store after the upload; entries no kept release holds are removed there.

The digest of secret content (a `secret: true` file, a secret's value in the hash label) is
an HMAC with a key the controller derives and never writes (secret_key): an unsalted
sha256 of a PIN, in a world-readable compose.yml or folder name, gives the PIN back by
brute force in milliseconds. The key is the same for the same inputs, so an unchanged
secret keeps its address and its containers.

Rollback needs nothing more: a kept release's compose.yml names its own store paths,
which exist as long as the release is kept, so compose recreates exactly what differs.
"""
from __future__ import annotations

import dataclasses
import hashlib
import hmac
import json
from typing import Any, Mapping

from rosdeploy.commands import Command, load, script
from rosdeploy.model import RenderedFile, RenderedRelease

HASH_LABEL = "io.rosdeploy.hash"
STORE = "store"
HASH_CHARS = 16

# Context keys every service shares in compose.yml (x-ros-common and the DDS file).
_COMMON = ("dds_env", "network_mode", "shm_size", "log_max_size", "log_max_file", "ros_domain_id",
           "rmw_implementation", "dds_file", "dds_source")


def content_digest(content: str, key: bytes | None = None) -> str:
    """sha256 of public content; an HMAC under `key` (secret_key) for secret content, so the
    digest is no test of a guess of the content."""
    data = content.encode("utf-8", "surrogatepass")
    if key is None:
        return hashlib.sha256(data).hexdigest()[:HASH_CHARS]
    return hmac.new(key, data, hashlib.sha256).hexdigest()[:HASH_CHARS]


def stored(file: RenderedFile, name: str | None = None, key: bytes | None = None) -> RenderedFile:
    """The copy of a rendered file that containers mount: store/<digest>/<name>; a secret file's
    digest is keyed (`key` is required for one)."""
    if file.secret and key is None:
        raise ValueError(f"{file.name} is secret: its store address needs the secret key")
    base = (name or file.name).rsplit("/", 1)[-1]
    digest = content_digest(file.content, key if file.secret else None)
    return dataclasses.replace(file, name=f"{STORE}/{digest}/{base}")


def mount_source(file: RenderedFile) -> str:
    """Where compose finds a stored file, relative to the release dir (releases/<id>/)."""
    return f"../../{file.name}"


def service_hash(svc: Any, ctx: Mapping[str, Any], key: bytes) -> str:
    """Everything that makes this service's container what it is, and nothing else. `key`:
    secret_key, for the digests of the secret values it reads."""
    # The fields as they are, not dataclasses.asdict: its deep copy was a third of rendering
    # 5,000 robots (issue 18); _json_value turns a nested dataclass into the same JSON.
    fields = {k: v for k, v in _fields(svc).items() if k not in ("labels", "extra_yaml")}
    fields["labels"] = [kv for kv in svc.labels if kv[0] != HASH_LABEL]
    secrets = dict(ctx.get("secrets") or ())
    data = {"service": fields, "common": {k: ctx.get(k) for k in _COMMON},
            # a changed secret changes the container's environment; only its digest goes in
            "secrets": {name: content_digest(secrets.get(name, ""), key) for name in svc.secrets}}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=_json_value).encode()).hexdigest()[:HASH_CHARS]


def _json_value(value: Any) -> Any:
    """What json.dumps cannot write: a dataclass as its fields (json.dumps comes back here for a
    nested one, so the text is asdict's), anything else as its str."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _fields(value)
    return str(value)


def _fields(obj: Any) -> dict[str, Any]:
    """A dataclass instance's fields by name (its __dict__ holds exactly them, unless it uses slots)."""
    if hasattr(obj, "__dict__"):
        return vars(obj)
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def with_hash(svc: Any, ctx: Mapping[str, Any], key: bytes) -> Any:
    labels = tuple(kv for kv in svc.labels if kv[0] != HASH_LABEL)
    return dataclasses.replace(svc, labels=labels + ((HASH_LABEL, service_hash(svc, ctx, key)),))


def hashes(compose: Mapping[str, Any] | None) -> dict[str, str]:
    """service -> hash label, from a release's compose data (as written)."""
    services = (compose or {}).get("services") or {}
    return {name: str((svc.get("labels") or {}).get(HASH_LABEL, "")) for name, svc in services.items()}


def will_restart(new: Mapping[str, str], running: Mapping[str, str]) -> tuple[str, ...]:
    """Services whose container a switch recreates: new, or running with another hash."""
    return tuple(sorted(name for name, h in new.items() if not h or running.get(name) != h))


LINK_STORE_SCRIPT = load("link-store.sh")


def link_store(root: str, project: str, release: str) -> Command:
    """After the upload: the release's stored files at their stable paths."""
    return script("link-store", LINK_STORE_SCRIPT, root, project, release)


def release_hashes(release: RenderedRelease) -> dict[str, str]:
    """service -> hash label of a rendered release (a user's compose template is parsed back)."""
    if release.compose_data is not None:
        return hashes(release.compose_data[0])
    import yaml
    try:
        return hashes(yaml.safe_load(release.file("compose.yml").content))
    except (yaml.YAMLError, StopIteration, AttributeError):
        return {}
