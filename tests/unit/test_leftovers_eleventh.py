"""Round eleven: leftovers of earlier rounds."""
from __future__ import annotations

from pathlib import Path

import pytest

from test_hostile import cli, edit, lab  # noqa: F401  (lab is a fixture)


@pytest.mark.parametrize("tmpfs, index, words", [
    (["/proc/foo"], 0, "a tmpfs at /proc/foo is in /proc, where the container runtime (runc) refuses a mount"),
    (["/run", "/sys/class/x"], 1, "a tmpfs at /sys/class/x is in /sys, the container's read-only sysfs"),
    (["/sys"], 0, "a mount at /sys would hide the container's sysfs"),
    (["/run/../proc:size=1m"], 0, "a tmpfs at /proc is in /proc"),
])
def test_a_compose_tmpfs_in_proc_or_sys_is_refused_by_every_command(
        capsys: pytest.CaptureFixture, lab: Path, tmpfs: list, index: int, words: str) -> None:  # noqa: F811
    edit(lab, lambda d: d["services"]["driver"].update(compose={"tmpfs": tmpfs}))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and f"services.driver.compose.tmpfs[{index}]: {words}" in text, (command, text)
        assert "Traceback" not in text
    assert not (lab / "out").exists()


def test_a_compose_tmpfs_elsewhere_still_renders(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    edit(lab, lambda d: d["services"]["driver"].update(compose={"tmpfs": ["/run/cache:size=1m", "/proc-like"]}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "/run/cache:size=1m" in next((lab / "out").glob("*/compose.yml")).read_text()


@pytest.mark.parametrize("root, words", [("/proc/x", "is in /proc, the kernel's own file system"),
                                         ("/dev", "is in /dev, the kernel's own file system"),
                                         ("/.", "is the robot's root folder")])
def test_a_robot_s_deploy_root_is_checked_like_the_fleet_s(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                           root: str, words: str) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(f"gpu: true\nrosdeploy_deploy_root: {root}\n")
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "host_vars/r1.yml:2: rosdeploy_deploy_root" in text and words in text, (command, text)
    assert not (lab / "out").exists()


def test_a_device_path_with_dotdot_is_refused_for_the_dotdot(
        capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    (lab / "inventory" / "host_vars" / "r1.yml").write_text("gpu: true\ndevices: {motor: /dev/../dev/mem}\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "'/dev/../dev/mem' holds `..`" in text and "not /dev itself" not in text, text


def test_a_host_name_the_resolver_refuses_at_connect_is_that_robot_s_error(
        capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    # `%h` expands only when connecting, so validate cannot judge it: the resolver's IDNA codec
    # raised UnicodeError there, an internal error (exit 1) for the whole command
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("ansible_host: 127.0.0.1", "ansible_port: 22"))
    (lab / "ssh_config").write_text("Host r1\n  HostName %h..x\n")
    (lab / "known_hosts").write_text("")
    edit(lab, lambda d: d.update(ssh={"config": "ssh_config", "known_hosts": "known_hosts", "connect_timeout": "2s"}))
    code, text = cli(capsys, lab, "plan", "--limit", "r1")
    assert code == 3 and "r1..x is not a valid host name" in text, text


@pytest.mark.parametrize("kind", ["toml", "script"])
def test_a_nul_in_a_toml_or_script_inventory_is_refused_at_the_var(
        capsys: pytest.CaptureFixture, lab: Path, kind: str) -> None:  # noqa: F811
    (lab / "inventory" / "hosts.yml").unlink()
    if kind == "toml":
        (lab / "inventory" / "hosts.toml").write_text(
            '[lab.hosts]\nr1 = { ansible_host = "127.0.0.1", ros_domain_id = 1, site = "a\\u0000b" }\n'
            'r2 = { ansible_host = "127.0.0.2", ros_domain_id = 2 }\n')
    else:
        script = lab / "inventory" / "dyn.py"
        script.write_text("#!/usr/bin/env python3\nimport json\nprint(json.dumps({'lab': {'hosts': ['r1', 'r2']}, "
                          "'_meta': {'hostvars': {'r1': {'ansible_host': '127.0.0.1', 'ros_domain_id': 1, "
                          "'site': 'a\\x00b'}, 'r2': {'ansible_host': '127.0.0.2', 'ros_domain_id': 2}}}}))\n")
        script.chmod(0o755)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "site" in text and "NUL byte (U+0000)" in text, text


def test_a_key_path_spells_keys_that_are_no_string_as_yaml_does() -> None:
    from rosdeploy.yamlsrc import dotted
    assert dotted(("hosts", True)) == "hosts[true]" and dotted(("hosts", None)) == "hosts[null]"
    assert dotted(("hosts", 1.5)) == "hosts[1.5]" and dotted(("a", "b", 0, "c")) == "a.b[0].c"


# ------------------------------------------------------------ the review's mends (reviewers A and B)

COMPOSE_SH = Path(__file__).resolve().parents[2] / "rosdeploy" / "scripts" / "_compose.sh"


def test_compose_runs_without_the_robot_s_values_of_the_names_env_sets(tmp_path: Path) -> None:
    """A secret named like the script's own `flavor`, `export NAME=` and blanks around a name (a
    user's env.j2): each name .env sets is gone for compose, the script's choice of compose stays."""
    import subprocess
    (tmp_path / ".env").write_text("# c\nROS_DOMAIN_ID=1\nflavor=zz\n SPACED = 5\nexport EXP=6\nexport\tTAB=7\n"
                                   "PATH=/nope\n1A=2\nnoeq\n")
    script = (f"set -u\nflavor=v2\n. {COMPOSE_SH}\n"
              "docker() { echo \"docker $*\"; env | grep -E '^(ROS_DOMAIN_ID|SPACED|EXP|TAB|KEEP)=' | sort; "
              "[ -n \"$PATH\" ] && echo path-kept; }\n"
              "export ROS_DOMAIN_ID=99 SPACED=s EXP=e TAB=t KEEP=k\ncompose ps\n"
              "echo \"after $ROS_DOMAIN_ID $flavor\"\n")
    done = subprocess.run(["sh", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=10)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["docker compose ps", "KEEP=k", "path-kept", "after 99 v2"], done.stdout


@pytest.mark.parametrize("size", ["20GiB", "1t", "10 GB", "512m"])
def test_a_storage_opt_size_docker_reads_passes(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                size: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose={"storage_opt": {"size": size}}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0, text


def test_a_template_value_of_a_shape_the_schema_refuses_is_left_to_the_schema_check() -> None:
    from rosdeploy.checks import _value_refusals
    values = {"blkio_config": {1: [{"path": "/dev/sda", "rate": "1mb"}]}}
    assert _value_refusals(repr(values), values) == ()    # raised AttributeError: an internal error


def test_a_template_line_is_named_only_for_a_whole_line_of_the_template(tmp_path: Path) -> None:
    from rosdeploy.checks import template_line
    template = tmp_path / "compose.yml.j2"
    template.write_text("a: 10\nb: {{ v }}\n  c: !foo 1\n")
    assert template_line(str(template), "a: 10\nb: 1\n", 2) is None        # `b: 1` was written by a value
    assert template_line(str(template), "a: 10\nb: 1\nc: !foo 1\n", 3) == 3
    template.write_text("x: 10\nx: {{ v }}\n")
    assert template_line(str(template), "x: 10\nx: 1\n", 2) is None        # `x: 1` is in `x: 10`, not its writer


def test_a_yaml_inventory_with_a_bad_value_gets_no_ini_reading(tmp_path: Path) -> None:
    from rosdeploy.errors import InputError
    from rosdeploy.inventory import load_inventory
    (tmp_path / "hosts.yml").write_text('all:\n  hosts:\n    r1:\n      zz: "a\\0b"\n')
    with pytest.raises(InputError) as raised:
        load_inventory(str(tmp_path / "hosts.yml"))
    text = "\n".join(map(str, raised.value.problems))
    assert "hosts.yml:4" in text and "NUL byte" in text and "INI" not in text, text
