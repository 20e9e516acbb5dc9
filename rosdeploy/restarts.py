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

Rollback needs nothing more: a kept release's compose.yml names its own store paths,
which exist as long as the release is kept, so compose recreates exactly what differs.
"""
from __future__ import annotations

import dataclasses
import hashlib
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


def content_digest(content: str) -> str:
    return hashlib.sha256(content.encode("utf-8")).hexdigest()[:HASH_CHARS]


def stored(file: RenderedFile, name: str | None = None) -> RenderedFile:
    """The copy of a rendered file that containers mount: store/<digest>/<name>."""
    base = (name or file.name).rsplit("/", 1)[-1]
    return dataclasses.replace(file, name=f"{STORE}/{content_digest(file.content)}/{base}")


def mount_source(file: RenderedFile) -> str:
    """Where compose finds a stored file, relative to the release dir (releases/<id>/)."""
    return f"../../{file.name}"


def service_hash(svc: Any, ctx: Mapping[str, Any]) -> str:
    """Everything that makes this service's container what it is, and nothing else."""
    fields = {k: v for k, v in dataclasses.asdict(svc).items() if k not in ("labels", "extra_yaml")}
    fields["labels"] = [kv for kv in svc.labels if kv[0] != HASH_LABEL]
    secrets = dict(ctx.get("secrets") or ())
    data = {"service": fields, "common": {k: ctx.get(k) for k in _COMMON},
            # a changed secret changes the container's environment; only its digest goes in
            "secrets": {name: content_digest(secrets.get(name, "")) for name in svc.secrets}}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:HASH_CHARS]


def with_hash(svc: Any, ctx: Mapping[str, Any]) -> Any:
    labels = tuple(kv for kv in svc.labels if kv[0] != HASH_LABEL)
    return dataclasses.replace(svc, labels=labels + ((HASH_LABEL, service_hash(svc, ctx)),))


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
