"""Fixer G, round ten: `compose:` numbers written as strings, mounts in /sys, octal-looking
numbers in the fleet file."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rosdeploy import fleet
from rosdeploy.cli import main
from test_hostile import cli, edit, lab  # noqa: F401  (lab is a fixture)


def _compose(lab: Path, extra: dict, interpolate: bool | None = None) -> None:  # noqa: F811
    def change(d: dict) -> None:
        d["services"]["driver"]["compose"] = extra
        d["services"]["driver"]["resources"] = {"memory": "256m"}    # cpus would refuse cpu_quota beside it
        if interpolate is not None:
            d["services"]["driver"]["compose_interpolate"] = interpolate
    edit(lab, change)


def test_number_or_string_compose_keys_come_from_the_schema() -> None:
    assert dict(fleet.compose_number_keys()) == {
        "cpu_shares": "integer", "cpu_quota": "integer", "cpu_period": "integer", "cpu_rt_period": "integer",
        "cpu_rt_runtime": "integer", "mem_reservation": "size", "memswap_limit": "size", "pids_limit": "integer"}


@pytest.mark.parametrize("extra, words", [
    ({"pids_limit": "abc"}, "'abc' is not a whole number"),
    ({"cpu_shares": "1e3"}, "'1e3' is not a whole number"),
    ({"cpu_shares": " 12"}, "' 12' is not a whole number"),
    ({"cpu_shares": "0x10"}, "'0x10' is not a whole number"),
    ({"pids_limit": 12.5}, "12.5 is not a whole number"),
    ({"cpu_quota": "50ms"}, "'50ms' is not a whole number of microseconds"),
    ({"mem_reservation": "abc"}, "'abc' is not a size in bytes"),
    ({"memswap_limit": "1x"}, "'1x' is not a size in bytes"),
])
def test_a_string_compose_cannot_cast_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                 extra: dict, words: str) -> None:
    _compose(lab, extra)
    key = next(iter(extra))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and f"services.driver.compose.{key}: {words}" in text, text
        assert f"Compose reads {key} as one" in text, text
    assert not (lab / "out").exists()


def test_a_dollar_without_interpolation_is_refused_with_the_way_to_interpolate(
        capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    _compose(lab, {"pids_limit": "${PIDS}"})
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "compose_interpolate: true" in text and "compose.pids_limit" in text, text


def test_an_interpolation_is_left_to_the_robot(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    _compose(lab, {"pids_limit": "${PIDS:-100}", "cpu_shares": "512"}, interpolate=True)
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    service = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]
    assert service["pids_limit"] == "${PIDS:-100}" and service["cpu_shares"] == 512


def test_a_number_written_as_a_string_is_written_as_the_number(capsys: pytest.CaptureFixture,
                                                                lab: Path) -> None:  # noqa: F811
    # Compose v1's docker-py refuses "12" where it wants an int, and reads cpu_quota "50000" as a
    # duration (it crashes); v2 casts both: only the number itself works on both
    _compose(lab, {"pids_limit": "12", "cpu_shares": "+512", "cpu_quota": "50000", "cpu_period": 100000.0,
                   "mem_reservation": "64m"})
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    service = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]
    assert (service["pids_limit"], service["cpu_shares"], service["cpu_quota"], service["cpu_period"]) == \
        (12, 512, 50000, 100000)
    assert all(type(service[k]) is int for k in ("pids_limit", "cpu_shares", "cpu_quota", "cpu_period"))
    assert service["mem_reservation"] == "64m"


# ------------------------------------------------------------------ 2. mounts in /sys

@pytest.mark.parametrize("volume, words", [
    ("/data:/sys/kernel/x", "/sys/kernel/x is in /sys, the container's read-only sysfs"),
    ("/data:/sys/./class/x/", "/sys/class/x is in /sys"),
    ("/data:/sys", "a mount at /sys would hide the container's sysfs"),
])
def test_a_volume_target_in_sys_is_refused(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                           volume: str, words: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=[volume]))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "services.driver.volumes[0]" in text and words in text, (command, text)


def test_a_file_target_in_sys_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    (lab / "p.yaml").write_text("a: 1\n")
    edit(lab, lambda d: (d.update(files={"a": {"copy": "p.yaml", "target": "/sys/fs/x"}}),
                         d["services"]["driver"].update(files=["a"])))
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "files.a.target: /sys/fs/x is in /sys" in text and "runc" in text, text
    assert "robot's own" not in text     # a file's source is the release, never the robot's sysfs


@pytest.mark.parametrize("volume", ["/sys:/sys:ro", "/sys/class/gpio:/sys/class/gpio", "/sys/bus/iio:/iio"])
def test_the_robots_own_sysfs_path_at_its_place_is_allowed(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                           volume: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=[volume]))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


# ------------------------------------------------------------------ 3. octal-looking numbers

def _octal_lab(lab: Path, text: str) -> Path:  # noqa: F811
    path = lab / "fleet.yml"
    path.write_text(path.read_text() + text)
    return path


def test_octal_looking_numbers_in_the_fleet_file_are_warned_of_at_file_and_line(lab: Path) -> None:  # noqa: F811
    path = _octal_lab(lab, "    compose: {ports: ['8080:80', 017], configs: [{source: c, mode: 0440}]}\n"
                           "vars: {site_port: 017, small: 07, none: 0, text: '017'}\n"
                           "logging: {max_file: 010}\n")
    spec = fleet.load_fleet(path)
    warnings = spec.warnings
    assert spec.vars["site_port"] == 15      # read as Ansible reads it, only warned of
    found = {(w.key, w.line, w.severity) for w in warnings}
    lines = path.read_text().splitlines()
    at = {key: next(i for i, line in enumerate(lines, 1) if word in line)
          for key, word in (("compose", "compose:"), ("vars", "vars:"), ("logging", "logging:"))}
    assert found == {("services.bridge.compose.ports[1]", at["compose"], "warning"),
                     ("vars.site_port", at["vars"], "warning"),
                     ("logging.max_file", at["logging"], "warning")}, warnings
    text = "\n".join(str(w) for w in warnings)
    assert "`017` is read as octal (15)" in text and "write 15, or 17 if that is meant" in text, text
    assert "mode" not in text                 # `mode: 0440` is octal on purpose


def test_a_duplicate_key_in_the_fleet_file_stays_an_error(lab: Path) -> None:  # noqa: F811
    path = _octal_lab(lab, "vars: {a: 1}\nvars: {a: 2}\n")
    with pytest.raises(fleet.FleetSpecError, match="duplicate key"):
        fleet.load_fleet(path)


def test_validate_and_check_show_an_octal_number_in_the_fleet_file(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    path = _octal_lab(lab, "vars: {site_port: 017}\n")
    line = len(path.read_text().splitlines())
    for command in ("validate", "check"):
        code = main([command, str(path), "--vault-password-file", str(lab / "inventory" / ".vault-password")])
        out = capsys.readouterr()
        text = out.out + out.err
        assert code == 0, text
        assert f"fleet.yml:{line}: vars.site_port: `017` is read as octal (15)" in text, text


def test_an_inventory_that_is_a_symlink_loop_is_named_so(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    loop = lab / "loop"
    loop.symlink_to(loop)
    code = main(["validate", str(lab / "fleet.yml"), "-i", str(loop)])
    text = capsys.readouterr().err
    assert code == 2 and f"{loop} is a symbolic link loop" in text and "does not exist" not in text, text
