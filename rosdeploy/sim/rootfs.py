"""Debian base images made with debootstrap, since no base image can be pulled here.

The package mirror is never written into rosdeploy: it is read from this host's
own apt sources (or ROSDEPLOY_SIM_MIRROR), so the sim uses whatever mirror the
machine is set up with.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from rosdeploy.errors import SimError
from rosdeploy.sim.proc import Progress, run, run_logged, tail

APT_SOURCES = Path("/etc/apt/sources.list")
APT_SOURCES_DIR = Path("/etc/apt/sources.list.d")

# Docs, manuals, translations and apt's caches: nothing a container runs needs them,
# and they are a third of a minbase rootfs.
TRIM = ("var/cache/apt/*.bin", "var/cache/apt/archives/*.deb", "var/lib/apt/lists/*_*",
        "usr/share/doc/*", "usr/share/man/*", "usr/share/info/*", "usr/share/locale/*/")


@dataclass(frozen=True)
class RootfsSpec:
    name: str                      # image name under rosdeploy-sim/
    packages: tuple[str, ...]      # debootstrap --include on top of minbase


def host_codename(os_release: Path = Path("/etc/os-release")) -> str:
    for line in os_release.read_text().splitlines():
        key, _, value = line.partition("=")
        if key == "VERSION_CODENAME" and value.strip('"'):
            return value.strip('"')
    raise SimError(f"cannot tell the Debian release from {os_release}; the simulator needs a Debian host")


def mirror_from_sources(texts: Iterable[tuple[str, str]], suite: str) -> str | None:
    """The first `deb` URI serving `suite` exactly, from (file name, content) pairs.

    Reads both the one-line format (*.list) and deb822 (*.sources).
    """
    for name, text in texts:
        entries = _deb822_entries(text) if name.endswith(".sources") else _one_line_entries(text)
        for types, uris, suites in entries:
            if "deb" in types and suite in suites and uris:
                return uris[0].rstrip("/")
    return None


def _one_line_entries(text: str) -> list[tuple[list[str], list[str], list[str]]]:
    entries = []
    for line in text.splitlines():
        words = line.split("#", 1)[0].split()
        if words and words[0] in ("deb", "deb-src"):
            words = [w for w in words if not w.startswith("[") and not w.endswith("]")]  # [opts]
            if len(words) >= 3:
                entries.append(([words[0]], [words[1]], [words[2]]))
    return entries


def _deb822_entries(text: str) -> list[tuple[list[str], list[str], list[str]]]:
    entries = []
    for paragraph in text.split("\n\n"):
        fields: dict[str, list[str]] = {}
        for line in paragraph.splitlines():
            key, sep, value = line.partition(":")
            if sep and not line.startswith(("#", " ")):
                fields[key.strip().lower()] = value.split()
        if fields.get("enabled", ["yes"])[0].lower() != "no":
            entries.append((fields.get("types", []), fields.get("uris", []), fields.get("suites", [])))
    return entries


def host_mirror(suite: str) -> str:
    configured = os.environ.get("ROSDEPLOY_SIM_MIRROR")
    if configured:
        return configured
    files = ([APT_SOURCES] if APT_SOURCES.exists() else []) + sorted(APT_SOURCES_DIR.glob("*.list")) \
        + sorted(APT_SOURCES_DIR.glob("*.sources"))
    mirror = mirror_from_sources(((f.name, f.read_text(errors="replace")) for f in files), suite)
    if not mirror:
        raise SimError(f"no Debian mirror for {suite!r} in /etc/apt/sources.list(.d); "
                       "set ROSDEPLOY_SIM_MIRROR to one")
    return mirror


def build_rootfs_image(spec: RootfsSpec, suite: str, tag: str, labels: dict[str, str],
                       workdir: Path, log: Path, progress: Progress) -> None:
    """debootstrap minbase + spec.packages, trim it, and `docker import` it as `tag`."""
    target = workdir / spec.name
    try:
        run_logged(("debootstrap", "--variant=minbase", f"--include={','.join(spec.packages)}",
                    suite, str(target), host_mirror(suite)),
                   what=f"debootstrap {spec.name}", log=log, progress=progress)
        trim(target)
        docker_import(target, tag, labels)
    finally:
        remove_tree(target)


def trim(root: Path) -> None:
    for pattern in TRIM:
        for path in root.glob(pattern):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()


def docker_import(root: Path, tag: str, labels: dict[str, str]) -> None:
    changes = [arg for key, value in labels.items() for arg in ("--change", f"LABEL {key}={value}")]
    tar = subprocess.Popen(["tar", "-C", str(root), "--numeric-owner", "-c", "."],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert tar.stdout is not None and tar.stderr is not None     # both pipes, as asked
    try:
        imported = run(("docker", "import", *changes, "-", tag), what=f"docker import {tag}",
                       check=False, stdin=tar.stdout)
    finally:
        tar.stdout.close()
        tar_err = tar.stderr.read().decode(errors="replace")
        tar.wait()
    if tar.returncode != 0 or imported.returncode != 0:
        raise SimError(f"importing {root} as {tag} failed: {tail(tar_err + imported.stderr)}")


def remove_tree(root: Path) -> None:
    """rm -rf a chroot, after unmounting anything a failed debootstrap left mounted in it."""
    if not root.exists():
        return
    prefix = str(root.resolve()) + "/"
    mounts = [line.split()[1] for line in Path("/proc/self/mounts").read_text().splitlines()]
    for mount in sorted((m for m in mounts if m.startswith(prefix)), key=len, reverse=True):
        run(("umount", "-l", mount), what=f"umount {mount}", check=False)
    shutil.rmtree(root)
