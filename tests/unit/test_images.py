"""rosdeploy.images without robots: rates, pacing, the fleet file's `images:`, the robot
command, stage images, bundles read back, per-robot vars."""
from __future__ import annotations

import hashlib
import io
import json
import subprocess
import tarfile
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from rosdeploy.errors import FleetSpecError, InputError
from rosdeploy.fleet import load_fleet
from rosdeploy.images.bundle import META, Bundle, BundleBackend, blob_path
from rosdeploy.images.forward import Limiter
from rosdeploy.images.pull import PULL_SCRIPT, command
from rosdeploy.images.refs import Layer, Pin, parse_rate, split_ref
from rosdeploy.images.relay import STAGE_LABEL, Relay
from rosdeploy.images.supply import check_vars
from rosdeploy.model import Host

DIGEST = "sha256:" + "a" * 64


def fleet(tmp_path: Path, **changes) -> Path:
    (tmp_path / "inv.yml").write_text("all: {hosts: {r1: {}}}\n")
    data = {"project": "p", "inventory": "inv.yml", "registry": "registry.local:5000", "version": "1.0.0",
            "services": {"driver": {"image": "acme/driver"}}, **changes}
    path = tmp_path / "fleet.yml"
    path.write_text(yaml.safe_dump(data))
    return path


# ------------------------------------------------------------------ values

@pytest.mark.parametrize("text, rate", [("2MB/s", 2e6), ("500kB/s", 5e5), ("1.5MiB/s", 1.5 * 2 ** 20),
                                        ("3 GBps", 3e9), (1000, 1000.0)])
def test_rates_read_as_bytes_per_second(text, rate) -> None:
    assert parse_rate(text) == rate


@pytest.mark.parametrize("text", ["2MB", "fast", "0MB/s", "-1MB/s", "2Mb/s/s", 0,
                                  # not finite, or so slow the pacing overflowed time_t (1e-7 B/s)
                                  float("nan"), float("inf"), 1e-7, "0.0000001B/s", "999B/s"])
def test_a_wrong_rate_is_refused(text) -> None:
    with pytest.raises(ValueError):
        parse_rate(text)


@pytest.mark.parametrize("text", ["2Mbps", "2Mb/s", "500kbps"])
def test_a_rate_in_bits_is_refused_with_the_bytes_to_write(text) -> None:
    # `2Mbps` was read as 2 MB/s: eight times the cap the user meant
    with pytest.raises(ValueError, match="bits per second; write bytes"):
        parse_rate(text)


def test_refs_split_into_registry_repository_tag() -> None:
    assert split_ref("registry.local:5000/demo/driver:1.0.0") == ("registry.local:5000", "demo/driver", "1.0.0")
    assert split_ref("acme/driver:2") == ("", "acme/driver", "2")
    assert split_ref(f"localhost/acme/driver@{DIGEST}") == ("localhost", "acme/driver", "")


def test_the_fleet_file_images_section(tmp_path: Path) -> None:
    spec = load_fleet(fleet(tmp_path, images={"via": "ssh", "max_rate": "2MB/s", "total_rate": "10MB/s",
                                              "controller_registry": "http://127.0.0.1:5000"}))
    assert (spec.images.via, spec.images.max_rate, spec.images.total_rate) == ("ssh", 2e6, 1e7)
    assert spec.images.controller_registry == "http://127.0.0.1:5000"
    assert load_fleet(fleet(tmp_path)).images.via == "registry"


def test_wrong_images_values_name_their_key(tmp_path: Path) -> None:
    with pytest.raises(FleetSpecError) as info:
        load_fleet(fleet(tmp_path, images={"via": "usb", "max_rate": "fast", "contoller_registry": "x"}))
    found = {p.key: p.message for p in info.value.problems}
    assert "registry" in found["images.via"] and "ssh" in found["images.via"]
    assert "2MB/s" in found["images.max_rate"]
    assert "images.contoller_registry" in found


def test_an_image_pinned_by_digest_is_valid_input(tmp_path: Path) -> None:
    spec = load_fleet(fleet(tmp_path, services={"driver": {"image": f"acme/driver@{DIGEST}"}}))
    driver = spec.service("driver")
    assert (driver.image, driver.tag, driver.digest) == ("acme/driver", "1.0.0", DIGEST)
    assert spec.image_ref(driver) == "registry.local:5000/acme/driver:1.0.0", "the normal name stays a tag"
    with pytest.raises(FleetSpecError) as info:
        load_fleet(fleet(tmp_path, services={"driver": {"image": "acme/driver@sha256:abc"}}))
    assert "64 hex" in str(info.value.problems[0])


def test_per_robot_vars_are_checked_naming_the_robot() -> None:
    good = Host("r1", ("all",), {"rosdeploy_images_via": "ssh", "rosdeploy_images_max_rate": "1MB/s"}, "r1")
    bad = Host("r2", ("all",), {"rosdeploy_images_via": "usb", "rosdeploy_images_max_rate": "quick"}, "r2",
               source="inv.yml:3")
    assert check_vars([good]) == []
    problems = check_vars([good, bad])
    assert len(problems) == 2 and all("r2" in p and "inv.yml:3" in p for p in problems)


# ------------------------------------------------------------------ pacing

def test_a_limiter_holds_its_rate() -> None:
    limiter = Limiter(1_000_000, burst=0.0)
    began = time.monotonic()
    for _ in range(20):
        limiter.take(25_000)            # 500 kB at 1 MB/s
    assert 0.45 <= time.monotonic() - began <= 0.7


def test_no_cap_never_waits() -> None:
    began = time.monotonic()
    Limiter(None).take(10 ** 9)
    assert time.monotonic() - began < 0.01


# ------------------------------------------------------------------ the robot's command

def test_the_pull_command_passes_refs_as_arguments_and_checks_as_sh() -> None:
    pin = Pin("registry.local:5000/demo/driver:1.0.0", "demo/driver", DIGEST, "sha256:" + "b" * 64)
    cmd = command([pin], "127.0.0.1:4100", 30, {DIGEST: ("sha256:" + "c" * 64,)})
    assert cmd.argv[4:] == (pin.ref, f"127.0.0.1:4100/demo/driver@{DIGEST}", pin.image_id, "sha256:" + "c" * 64)
    direct = command([pin], None, 30)
    assert direct.argv[5] == f"registry.local:5000/demo/driver@{DIGEST}" and direct.argv[7] == "-"
    assert subprocess.run(["sh", "-n", "-c", PULL_SCRIPT]).returncode == 0


# ------------------------------------------------------------------ relay and bundles

class FakeBackend:
    def __init__(self, blobs: dict[str, bytes], manifests: dict[str, bytes]) -> None:
        self.blobs, self.manifests = blobs, manifests

    def manifest(self, name, ref):
        body = self.manifests.get(ref)
        return (body, "application/vnd.docker.distribution.manifest.v2+json", ref) if body else None

    def blob(self, name, digest, start):
        data = self.blobs.get(digest)
        return (len(data), iter([data[start:]])) if data is not None else None


def sha(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()


def test_the_relay_serves_stage_images_of_the_big_layers() -> None:
    big, small = b"x" * 2_000_000, b"y" * 10
    config = json.dumps({"architecture": "amd64", "os": "linux",
                         "rootfs": {"type": "layers", "diff_ids": [DIGEST, DIGEST, DIGEST]}}).encode()
    layers = [{"digest": sha(big), "size": len(big)}, {"digest": sha(small), "size": 10},
              {"digest": sha(big + b"2"), "size": len(big) + 1}]
    body = json.dumps({"schemaVersion": 2, "config": {"digest": sha(config), "size": len(config)},
                       "layers": layers}).encode()
    relay = Relay(FakeBackend({sha(config): config}, {sha(body): body}))
    try:
        stages = relay.stages_of(Pin("r/x:1", "x", sha(body), sha(config)))
        assert len(stages) == 1, "a stage after the big first layer; none after the small one"
        host, port = relay.address
        with urllib.request.urlopen(f"http://{host}:{port}/v2/x/manifests/{stages[0]}") as response:
            stage = json.loads(response.read())
            assert response.headers["Docker-Content-Digest"] == stages[0]
        assert stage["layers"] == layers[:1]
        with urllib.request.urlopen(f"http://{host}:{port}/v2/x/blobs/{stage['config']['digest']}") as response:
            staged = json.loads(response.read())
        assert staged["rootfs"]["diff_ids"] == [DIGEST] and staged["config"]["Labels"] == {STAGE_LABEL: "1"}
    finally:
        relay.close()


def test_a_bundle_is_read_in_place_and_a_damaged_one_is_found(tmp_path: Path) -> None:
    blob = b"layer bytes"
    path = tmp_path / "b.tar"
    meta = {"pins": {"r/demo/x:1": {"repository": "demo/x", "digest": sha(b"m"), "image_id": None,
                                    "layers": [[sha(blob), len(blob)]]}}}
    with tarfile.open(path, "w") as tar:
        for name, data in ((blob_path(sha(blob)), blob), (blob_path(sha(b"m")), b"m"),
                           (META, json.dumps(meta).encode())):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    bundle = Bundle.open(path)
    assert bundle.verify() == []
    assert bundle.pins()["r/demo/x:1"].layers == (Layer(sha(blob), len(blob)),)
    size, chunks = BundleBackend(bundle, bundle.pins()).blob("demo/x", sha(blob), 6)
    assert (size, b"".join(chunks)) == (len(blob), b"bytes")
    raw = path.read_bytes().replace(blob, b"LAYER BYTES")
    path.write_bytes(raw)
    assert Bundle.open(path).verify() == [blob_path(sha(blob))]


def test_a_file_that_is_no_bundle_says_so(tmp_path: Path) -> None:
    (tmp_path / "x.tar").write_text("not a tar")
    with pytest.raises(InputError, match="rosdeploy bundle"):
        Bundle.open(tmp_path / "x.tar")
