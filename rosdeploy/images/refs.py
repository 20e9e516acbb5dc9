"""Image references and the digests a run pins them to.

A *normal name* is what the compose file runs and what `status`, rollback and pruning
see (`registry.local:5000/demo/driver:1.0.0`); a *pin* is the content that name must
hold for this run (the manifest digest, and the image id when the manifest is one
platform's). The robot gets the pinned bytes and the normal name, whatever the route.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

DIGEST_RE = re.compile(r"sha256:[0-9a-f]{64}")
# B is bytes, as in `2MB/s`; a lower-case b is bits (`2Mbps`), and refused: docs/images.md
_RATE_RE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([kKmMgG]?)(i?)([bB])(?:/s|ps)\s*")
MIN_RATE = 1000.0     # bytes/s: below 1 kB/s an image of 100 MB takes over a day


@dataclass(frozen=True)
class Layer:
    digest: str
    size: int           # compressed, as the manifest says


@dataclass(frozen=True)
class Pin:
    ref: str                    # the normal name, e.g. registry.local:5000/demo/driver:1.0.0
    repository: str             # the registry API's name, e.g. demo/driver
    digest: str                 # manifest (or index) digest: what `docker pull …@digest` fetches
    image_id: str | None        # config digest = the engine's image id; None for a multi-platform index
    layers: tuple[Layer, ...] = ()
    forced: bool = False        # pinned by `image@sha256:…` in the fleet file, not by resolving the tag

    @property
    def size(self) -> int:
        return sum(layer.size for layer in self.layers)


def split_ref(ref: str) -> tuple[str, str, str]:
    """`host:port/path/repo:tag` -> (host:port, path/repo, tag). No host: ("", repo, tag)."""
    first, sep, rest = ref.partition("/")
    host = first if sep and ("." in first or ":" in first or first == "localhost") else ""
    name = rest if host else ref
    name = name.split("@", 1)[0]
    repository, _, tag = name.rpartition(":") if ":" in name.rsplit("/", 1)[-1] else (name, "", "")
    return host, repository, tag


def parse_rate(text: str | int | float) -> float:
    """`2MB/s`, `500kB/s`, `1.5MiB/s` (bytes, not bits) -> bytes per second, at least MIN_RATE;
    ValueError (its message says why) if not such a rate."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        rate = float(text)
    else:
        match = _RATE_RE.fullmatch(str(text))
        if not match:
            raise ValueError(f"{text!r} is not a rate")
        if match.group(4) == "b":
            raise ValueError(f"{text!r} is bits per second; write bytes (B), e.g. 250kB/s for 2Mbit/s")
        unit = 1024 if match.group(3) else 1000
        rate = float(match.group(1)) * unit ** " kmg".index(match.group(2).lower() or " ")
    if not MIN_RATE <= rate < float("inf"):      # nan fails this too
        raise ValueError(f"{text!r} is not a rate from 1kB/s up")
    return rate


def human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"
