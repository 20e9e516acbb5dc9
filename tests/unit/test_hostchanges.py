"""Host changes (udev rules, ROS log rotation): privileges, preflight, plan, and the robot
scripts run by the real `sh` against a scratch /etc (tools stubbed, so nothing touches this machine)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from rosdeploy import hostchanges, rotation
from rosdeploy.errors import FleetSpecError
from rosdeploy.fleet import load_fleet
from rosdeploy.model import Host, RenderedRelease, UdevDevice
from rosdeploy.render import Renderer

FLEET = {"project": "demo", "inventory": "./inventory", "registry": "registry.local:5000", "version": "1.0.0",
         "services": {"driver": {"image": "demo/driver", "devices": ["motor"]}}}


def _h(**vars: object) -> Host:
    return Host(name="r1", groups=("all",), vars=dict(vars), address="10.0.0.1", ros_domain_id=7, source="inv:2",
                devices={"motor": "/dev/robot/motor"}, udev=(UdevDevice("robot/motor", "tty", "0403", "6001"),))


def _fleet(tmp_path: Path, **logging: object) -> Path:
    (tmp_path / "inventory").mkdir(exist_ok=True)
    (tmp_path / "inventory" / "hosts.yml").write_text("all: {}\n")
    path = tmp_path / "fleet.yml"
    path.write_text(yaml.safe_dump({**FLEET, **({"logging": logging} if logging else {})}, sort_keys=False))
    return path


def _release(tmp_path: Path, **logging: object) -> RenderedRelease:
    return Renderer(load_fleet(_fleet(tmp_path, **logging))).render(_h(ansible_user="robot"))


# ------------------------------------------------------------- privileges

@pytest.mark.parametrize("vars,mode,refused", [
    ({"ansible_user": "root"}, "direct", ""),
    ({"ansible_user": "robot"}, "sudo-n", ""),
    ({"ansible_user": "robot", "ansible_become_password": "pw-1234"}, "sudo-S", ""),
    ({"ansible_user": "robot", "ansible_become": False}, "", "ansible_become is false"),
    ({"ansible_user": "robot", "ansible_become_user": "ros"}, "", "need root"),
    ({"ansible_user": "robot", "ansible_become_method": "su"}, "", "not supported")])
def test_become_follows_ansible_vars(vars: dict, mode: str, refused: str) -> None:
    how = hostchanges.become(_h(**vars))
    assert how.mode == mode and refused in how.refused and bool(how.refused) == bool(refused)


def test_the_sudo_password_goes_on_stdin_never_in_argv() -> None:
    how = hostchanges.become(_h(ansible_user="robot"), asked_password="s3cret-pw")
    cmd = hostchanges.install_command("~/rosdeploy", "demo", "1.0.0-abc", how, ("tty", "video4linux", "tty"))
    assert cmd.stdin == b"s3cret-pw\n" and not any("s3cret" in a for a in cmd.argv)
    assert "tty,video4linux" in cmd.argv


# ------------------------------------------------------------- preflight

@pytest.mark.parametrize("answer,words", [
    ("root no-sudo", ["sudo is not installed", "NOPASSWD", "--no-host-changes", "/etc/cron.d/rosdeploy-demo"]),
    ("root denied sudo: a password is required", ["a password is required", "--ask-become-pass"])])
def test_preflight_says_what_is_missing_and_how_to_grant_it(answer: str, words: list[str]) -> None:
    host = _h(ansible_user="robot")
    out = f"differs /etc/cron.d/rosdeploy-demo\n{answer}\nlogrotate yes\ncron yes\nudevadm no\n"
    found = hostchanges.problems(out, host, hostchanges.become(host), rotates=True)
    assert len(found) == 1 and all(w in found[0] for w in words), found


def test_nothing_that_differs_needs_no_root() -> None:
    host = _h(ansible_user="robot", ansible_become=False)
    out = "logrotate yes\ncron yes\nudevadm no\n"
    assert hostchanges.problems(out, host, hostchanges.become(host), rotates=True) == []
    differs = hostchanges.problems("differs /etc/logrotate.d/rosdeploy-demo\n" + out, host,
                                   hostchanges.become(host), rotates=True)
    assert len(differs) == 1 and "ansible_become is false" in differs[0]


def test_a_robot_without_logrotate_or_cron_is_told_what_to_install() -> None:
    host = _h(ansible_user="root")
    found = hostchanges.problems("logrotate no\ncron no\n", host, hostchanges.become(host), rotates=True)
    assert len(found) == 2
    assert "r1 has no logrotate" in found[0] and "apt-get install logrotate" in found[0]
    assert "r1 has no cron" in found[1] and "apt-get install cron" in found[1]
    assert hostchanges.problems("logrotate no\ncron no\n", host, hostchanges.become(host), rotates=False) == []


def test_the_check_sends_each_target_with_the_digest_the_release_wants(tmp_path: Path) -> None:
    release = _release(tmp_path)
    cmd = hostchanges.check_command("~/rosdeploy", "demo", hostchanges.become(_h(ansible_user="root")),
                                    hostchanges.wanted(release, "demo"))
    args = list(cmd.argv[cmd.argv.index("direct") + 1:])
    assert args[0::2] == ["/etc/udev/rules.d/99-rosdeploy-demo.rules", "/etc/logrotate.d/rosdeploy-demo",
                          "/etc/cron.d/rosdeploy-demo"]
    assert all(len(d) == 64 for d in args[1::2])


# ------------------------------------------------------------- rendering and the fleet key

def test_the_schedule_is_rendered_from_rotate_every_and_listed_by_plan(tmp_path: Path) -> None:
    release = _release(tmp_path, rotate_every="2m")
    cron = release.file(rotation.CRON_FILE).content
    assert "*/2 * * * * root logrotate -s /var/lib/logrotate/rosdeploy-demo.status /etc/logrotate.d/rosdeploy-demo" \
        in cron
    conf = release.file(rotation.CONF_FILE).content
    assert "/root/rosdeploy/demo/logs/*/*.log {" in conf and "copytruncate" in conf and "su root root" in conf
    listed = hostchanges.describe(release, "demo")
    assert "udev rules" in listed[0] and "/etc/cron.d/rosdeploy-demo (`*/2 * * * *`" in listed[1]


def test_the_default_period_and_off(tmp_path: Path) -> None:
    assert hostchanges.schedule(_release(tmp_path)).startswith("*/5 * * * * root ")   # type: ignore[union-attr]
    off = _release(tmp_path, rotate_every="off")
    assert hostchanges.schedule(off) is None and len(hostchanges.describe(off, "demo")) == 1
    assert hostchanges.wanted(off, "demo")["/etc/cron.d/rosdeploy-demo"] is None


@pytest.mark.parametrize("seconds,fields", [(60, "* * * * *"), (900, "*/15 * * * *"), (3600, "0 */1 * * *"),
                                            (86400, "0 0 * * *"), (420, None), (90, None), (5 * 3600, None),
                                            (None, None)])
def test_cron_keeps_only_even_periods(seconds: float | None, fields: str | None) -> None:
    assert rotation.cron_schedule(seconds) == fields


@pytest.mark.parametrize("value,words", [("7m", ["'7m'", "15m", "or off"]), ("30s", ["once a minute"]),
                                         ("soon", ["duration"])])
def test_a_bad_period_names_the_file_line_and_the_choices(tmp_path: Path, value: str, words: list[str]) -> None:
    with pytest.raises(FleetSpecError) as info:
        load_fleet(_fleet(tmp_path, rotate_every=value))
    (problem,) = info.value.problems
    assert problem.file.endswith("fleet.yml") and problem.line and "rotate_every" in problem.key
    assert all(w in problem.message for w in words), problem.message


# ------------------------------------------------------------- the robot scripts, run by sh

STUB = """#!/bin/sh
echo "$(basename "$0") $*" >> "$STUB_LOG"
[ "$(basename "$0")" != logrotate ] || [ -z "${LOGROTATE_FAILS:-}" ] || { echo "error: bad line" >&2; exit 1; }
"""


@pytest.fixture
def robot(tmp_path: Path) -> dict:
    """A scratch robot: a deploy root, an /etc, stubbed udevadm and logrotate."""
    stubs = tmp_path / "bin"
    stubs.mkdir()
    for tool in ("udevadm", "logrotate"):
        (stubs / tool).write_text(STUB)
        (stubs / tool).chmod(0o755)
    etc = tmp_path / "etc"
    targets = (str(etc / "udev/rules.d/99-rosdeploy-demo.rules"), str(etc / "logrotate.d/rosdeploy-demo"),
               str(etc / "cron.d/rosdeploy-demo"))
    env = {**os.environ, "PATH": f"{stubs}:/usr/bin:/bin", "STUB_LOG": str(tmp_path / "stub.log")}
    return {"root": tmp_path / "deploy", "targets": targets, "state": str(tmp_path / "state"), "env": env,
            "log": tmp_path / "stub.log", "dev": tmp_path / "dev"}


def _put(robot: dict, release: str, files: dict[str, str]) -> None:
    folder = robot["root"] / "demo" / "releases" / release
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / name).write_text(text)


def _install(robot: dict, release: str, mode: str = "direct",
             devices: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    rules, conf, cron = robot["targets"]
    argv = ("sh", "-c", hostchanges.INSTALL_SCRIPT, "rosdeploy", str(robot["root"]), "demo", release, mode,
            hostchanges.ROOT_SCRIPT, "tty", rules, conf, cron, robot["state"], hostchanges.RESTORE_SCRIPT, *devices)
    return subprocess.run(argv, capture_output=True, text=True, env=robot["env"], timeout=30)


RULES = 'SUBSYSTEM=="tty", SYMLINK+="robot/motor"\n'
CRON = "# schedule\n*/1 * * * * root logrotate -s /s /c\n"


def test_install_places_the_files_then_needs_no_root_while_nothing_differs(robot: dict) -> None:
    _put(robot, "1.0.0-a", {"99-rosdeploy.rules": RULES, "logrotate.conf": "/x/*.log {\n}\n", "logrotate.cron": CRON})
    done = _install(robot, "1.0.0-a")
    assert done.returncode == 0, done.stderr
    rules, conf, cron = (Path(t) for t in robot["targets"])
    assert rules.read_text() == RULES and cron.read_text() == CRON and conf.read_text() == "/x/*.log {\n}\n"
    assert oct(cron.stat().st_mode & 0o777) == "0o644" and Path(robot["state"]).is_dir()
    assert "no udev on this robot" not in done.stdout and "udevadm verify: ok" in done.stdout   # the stub udevadm
    assert "logrotate -d -s /dev/null" in robot["log"].read_text(), "the config is checked before it is installed"
    again = _install(robot, "1.0.0-a", mode="refused")
    assert again.returncode == 0 and again.stdout.strip() == hostchanges.NOTHING, again


def test_a_release_without_a_schedule_removes_it_and_a_refused_config_installs_nothing(robot: dict) -> None:
    _put(robot, "1.0.0-a", {"99-rosdeploy.rules": RULES, "logrotate.conf": "c\n", "logrotate.cron": CRON})
    _put(robot, "0.9.0-b", {"99-rosdeploy.rules": "# none\n", "logrotate.conf": "c\n"})   # before log rotation
    assert _install(robot, "1.0.0-a").returncode == 0
    back = _install(robot, "0.9.0-b")
    assert back.returncode == 0 and not any(Path(t).exists() for t in robot["targets"]), back.stdout
    assert "refused" not in _install(robot, "0.9.0-b", mode="refused").stderr
    robot["env"]["LOGROTATE_FAILS"] = "1"
    bad = _install(robot, "1.0.0-a")
    assert bad.returncode == 6 and "logrotate refused the rotation config: error: bad line" in bad.stdout
    assert not Path(robot["targets"][2]).exists()


def test_root_refused_fails_only_when_something_differs(robot: dict) -> None:
    _put(robot, "1.0.0-a", {"99-rosdeploy.rules": RULES, "logrotate.conf": "c\n", "logrotate.cron": CRON})
    refused = _install(robot, "1.0.0-a", mode="refused")
    assert refused.returncode == hostchanges.NO_ROOT and not Path(robot["targets"][0]).exists()


def test_a_mapped_device_must_resolve_after_the_trigger(robot: dict) -> None:
    _put(robot, "1.0.0-a", {"99-rosdeploy.rules": RULES, "logrotate.conf": "c\n", "logrotate.cron": CRON})
    robot["dev"].mkdir()
    (robot["dev"] / "ttyUSB0").write_text("")
    present, absent = str(robot["dev"] / "ttyUSB0"), str(robot["dev"] / "robot motor;x")   # hostile: a plain argument
    ok = _install(robot, "1.0.0-a", devices=(present,))
    assert ok.returncode == 0 and f"devices resolve: {present}" in ok.stdout
    missing = _install(robot, "1.0.0-a", devices=(present, absent))
    assert missing.returncode == hostchanges.MISSING_DEVICE and f"missing-device {absent}" in missing.stdout


def test_a_missing_device_names_the_inventory_entry_and_its_rule() -> None:
    (message,) = hostchanges.missing_devices("installed x\nmissing-device /dev/robot/motor\n", _h())
    assert "`devices.motor`" in message and 'SYMLINK+="robot/motor" for 0403:6001' in message and "on r1" in message


def test_the_install_leaves_what_the_guard_needs_to_restore_a_release(robot: dict) -> None:
    _put(robot, "1.0.0-a", {"99-rosdeploy.rules": RULES, "logrotate.conf": "c\n", "logrotate.cron": CRON})
    _put(robot, "1.1.0-b", {"99-rosdeploy.rules": RULES.replace("motor", "drive"), "logrotate.conf": "c\n",
                            "logrotate.cron": CRON.replace("*/1", "*/10")})
    assert _install(robot, "1.0.0-a").returncode == 0 and _install(robot, "1.1.0-b").returncode == 0
    rules, _, cron = (Path(t) for t in robot["targets"])
    assert "*/10" in cron.read_text() and "drive" in rules.read_text()
    project = robot["root"] / "demo"
    restore = ("sh", str(project / ".host/restore.sh"), str(project))
    back = subprocess.run((*restore, "1.0.0-a"), capture_output=True, text=True, env=robot["env"], timeout=30)
    assert back.returncode == 0 and cron.read_text() == CRON and rules.read_text() == RULES, back
    assert subprocess.run((*restore, ""), env=robot["env"], timeout=30).returncode == 0    # no previous release
    args = project / ".host/args"
    args.write_text(args.read_text().replace("direct", "sudo-S", 1))
    refused = subprocess.run((*restore, "1.1.0-b"), capture_output=True, text=True, env=robot["env"], timeout=30)
    assert refused.returncode == 1 and "no password is kept" in refused.stdout and cron.read_text() == CRON


class _Robot:
    """A transport whose host-check answers `stdout`."""

    def __init__(self, stdout: str) -> None:
        self.stdout = stdout

    def run(self, command: Any) -> Any:
        from rosdeploy.transport import Result
        return Result(command.label, self.stdout, "", 0, 0.0)


@pytest.mark.parametrize("rules_differ,refused", [(True, False), (False, True)])
def test_a_device_a_rule_makes_waits_for_the_trigger_only_when_the_rules_change(
        tmp_path: Path, rules_differ: bool, refused: bool) -> None:
    answer = ("differs /etc/udev/rules.d/99-rosdeploy-demo.rules\nroot ok\n" if rules_differ else "") \
        + "logrotate yes\ncron yes\n"
    found = hostchanges.preflight(_Robot(answer), "~/rosdeploy", "demo", _h(ansible_user="root"),
                                  _release(tmp_path), missing=("/dev/robot/motor", "/dev/video0"))
    assert bool(found) == refused, found
    if refused:
        (message,) = found
        assert "/dev/robot/motor (`devices.motor`" in message and "with its udev rule installed already" in message


# ------------------------------------------------------------- drift (a no-op apply puts back, status says)

def _sha(text: str) -> str:
    import hashlib
    return hashlib.sha256(text.encode()).hexdigest()


def test_drift_names_each_installed_file_that_differs_from_the_release(tmp_path: Path) -> None:
    release = _release(tmp_path, rotate_every="5m")
    want = {t: text for t, text in hostchanges.wanted(release, "demo").items()}
    rules, conf, cron = hostchanges.targets("demo")
    assert all(want[t] for t in (rules, conf, cron)), want          # this release installs all three
    installed = {t: _sha(text) for t, text in want.items() if text is not None}
    assert hostchanges.drift(installed, release, "demo") == ()
    assert hostchanges.drift({**installed, cron: _sha("edited\n")}, release, "demo") == (cron,)
    assert hostchanges.drift({k: v for k, v in installed.items() if k != rules}, release, "demo") == (rules,)
    assert hostchanges.drift({**installed, conf: "?"}, release, "demo") == (), "unreadable: not judged"
    assert hostchanges.drift(None, release, "demo") == (), "the state did not look (a rollback's)"


def test_a_schedule_left_where_the_release_wants_none_is_drift(tmp_path: Path) -> None:
    release = _release(tmp_path, rotate_every="off")
    rules, conf, cron = hostchanges.targets("demo")
    installed = {rules: _sha(hostchanges.wanted(release, "demo")[rules] or "")}
    assert hostchanges.drift(installed, release, "demo") == ()
    assert hostchanges.drift({**installed, cron: _sha("* * * * * root logrotate\n")}, release, "demo") == (cron,)
