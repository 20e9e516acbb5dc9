"""validate / render / check through rosdeploy.cli.main: exit codes, messages, files, no tracebacks."""
from __future__ import annotations

import json
import shutil
import stat
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import main

REPO = Path(__file__).resolve().parents[2]
WAREHOUSE = str(REPO / "playbooks" / "warehouse.yml")
WAREHOUSE_PASSWORD = str(REPO / "inventory" / "warehouse" / ".vault-password-example")
WAREHOUSE_SECRET = "demo-4f9c2a7e1b8d4e6fa0c3"
DATA = Path(__file__).resolve().parent / "data" / "fleet"
LAB_SECRET = "unit-test-token-7d1e"


@pytest.fixture(autouse=True)
def no_vault_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD", raising=False)
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD_FILE", raising=False)


@pytest.fixture
def lab(tmp_path: Path) -> Path:
    """A private copy of tests/unit/data/fleet that a test may break."""
    shutil.copytree(DATA, tmp_path / "lab")
    return tmp_path / "lab"


def run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "internal error" not in captured.err, captured.err
    return code, captured.out, captured.err


def lab_run(capsys: pytest.CaptureFixture, lab: Path, command: str, *argv: str) -> tuple[int, str, str]:
    password = str(lab / "inventory" / ".vault-password")
    return run(capsys, command, str(lab / "fleet.yml"), "--vault-password-file", password, *argv)


def edit(path: Path, change) -> None:
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


# ------------------------------------------------------ the shipped example

def test_warehouse_example_validates(capsys: pytest.CaptureFixture) -> None:
    code, out, err = run(capsys, "validate", WAREHOUSE, "--vault-password-file", WAREHOUSE_PASSWORD)
    assert code == 0, err
    assert out.startswith(f"OK {WAREHOUSE}: project warehouse version 1.4.2, 5 service(s), 4 robot(s)")
    assert "error" not in err


def test_warehouse_example_checks_with_explained_warnings_only(capsys: pytest.CaptureFixture) -> None:
    code, out, err = run(capsys, "--json", "check", WAREHOUSE, "--vault-password-file", WAREHOUSE_PASSWORD)
    assert code == 0, err
    doc = json.loads(out)
    assert doc["ok"] and doc["robots"] == ["amr-n1", "amr-n2", "amr-s1", "amr-s2"]
    assert {f["rule"] for f in doc["findings"]} <= {"gpu-unavailable"}
    assert all(f["severity"] != "error" and f["fix"] for f in doc["findings"])


def test_render_writes_every_robot_with_modes_and_masks_secrets(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    code, out, err = run(capsys, "render", WAREHOUSE, "--out", str(tmp_path), "--limit", "site_north",
                         "--vault-password-file", WAREHOUSE_PASSWORD)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["amr-n1", "amr-n2"]
    files = {p.name: p for p in (tmp_path / "amr-n1").iterdir()}
    assert {"compose.yml", ".env", "fastdds.xml", "logrotate.conf", "99-rosdeploy.rules"} <= set(files)
    assert stat.S_IMODE(files[".env"].stat().st_mode) == 0o600
    assert stat.S_IMODE(files["compose.yml"].stat().st_mode) == 0o644
    assert WAREHOUSE_SECRET in files[".env"].read_text()
    assert "amr-n1" in out and "1.4.2-" in out and WAREHOUSE_SECRET not in out + err


def test_render_version_override_and_json(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    code, out, _ = run(capsys, "render", WAREHOUSE, "-o", str(tmp_path), "-l", "amr-s1", "--version", "2.0.0",
                       "--vault-password-file", WAREHOUSE_PASSWORD, "--json")
    assert code == 0
    robot = json.loads(out)["robots"][0]
    assert robot["robot"] == "amr-s1" and robot["release"].startswith("2.0.0-")
    assert {"name": ".env", "mode": "0600"} in robot["files"]
    assert "registry.local:5000/acme/amr-driver:2.0.0" in (tmp_path / "amr-s1" / "compose.yml").read_text()


def render_north(capsys: pytest.CaptureFixture, out: Path) -> tuple[int, str, str]:
    return run(capsys, "render", WAREHOUSE, "--out", str(out), "--limit", "site_north",
               "--vault-password-file", WAREHOUSE_PASSWORD)


def test_render_over_an_earlier_render_replaces_its_files_and_keeps_the_rest(capsys: pytest.CaptureFixture,
                                                                               tmp_path: Path) -> None:
    (tmp_path / "amr-n1").mkdir()
    (tmp_path / "amr-n1" / ".env").write_text("OLD=1\n")
    (tmp_path / "amr-n1" / ".env").chmod(0o644)
    (tmp_path / "amr-n1" / "notes.txt").write_text("mine\n")
    (tmp_path / "other").mkdir()
    code, _, err = render_north(capsys, tmp_path)
    assert code == 0, err
    env = tmp_path / "amr-n1" / ".env"
    assert WAREHOUSE_SECRET in env.read_text() and "OLD=1" not in env.read_text()
    assert stat.S_IMODE(env.stat().st_mode) == 0o600          # an old file's mode does not survive
    assert (tmp_path / "amr-n1" / "notes.txt").read_text() == "mine\n"
    assert (tmp_path / "amr-n2" / "compose.yml").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["amr-n1", "amr-n2", "other"]   # no staging left


def test_render_that_cannot_put_a_robot_in_place_says_where_and_leaves_no_staging(capsys: pytest.CaptureFixture,
                                                                                 tmp_path: Path) -> None:
    (tmp_path / "amr-n2").write_text("a file where the robot's folder goes\n")
    code, out, err = render_north(capsys, tmp_path)
    assert code == 2 and out == ""
    assert f"{tmp_path / 'amr-n2'}" in err and "cannot write there" in err and "--out" in err
    assert (tmp_path / "amr-n2").read_text() == "a file where the robot's folder goes\n"
    assert not any(p.name.startswith(".rosdeploy-render-") for p in tmp_path.iterdir())


def test_a_refused_fleet_leaves_an_existing_out_folder_as_it_was(capsys: pytest.CaptureFixture, lab: Path) -> None:
    out = lab / "out"
    (out / "r1").mkdir(parents=True)
    (out / "r1" / "compose.yml").write_text("earlier\n")
    edit(lab / "fleet.yml", lambda d: d["services"][next(iter(d["services"]))].update(privileged=True))
    code, _, err = lab_run(capsys, lab, "render", "--out", str(out))
    assert code == 2 and "privileged" in err
    assert [p.name for p in out.iterdir()] == ["r1"] and (out / "r1" / "compose.yml").read_text() == "earlier\n"


def test_render_where_out_cannot_be_made_names_the_path(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = render_north(capsys, blocker / "out")
    assert code == 2 and f"{blocker}" in err and "cannot write there" in err


def test_secrets_never_reach_the_output(capsys: pytest.CaptureFixture, lab: Path) -> None:
    for command in ("validate", "check"):
        code, out, err = lab_run(capsys, lab, command, "--json")
        assert code == 0 and LAB_SECRET not in out + err


# ------------------------------------------------------------------ overrides

def test_inventory_override(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d.update(inventory="./nowhere"))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "fleet.yml:2: inventory:" in err and "does not exist" in err
    code, out, _ = lab_run(capsys, lab, "validate", "-i", str(lab / "inventory"))
    assert code == 0 and "2 robot(s)" in out


def test_limit_that_matches_nothing(capsys: pytest.CaptureFixture, lab: Path) -> None:
    code, _, err = lab_run(capsys, lab, "validate", "--limit", "r9")
    assert code == 2 and "r9" in err


# ----------------------------------------------------------------- bad input

def test_malformed_yaml(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "fleet.yml").write_text("project: lab\nservices: {driver: [\n")
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "fleet.yml:3" in err and "invalid YAML" in err


def test_unknown_key_with_did_you_mean(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d["services"]["driver"].update(helthcheck={}))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "services.driver.helthcheck: unknown key `helthcheck`: did you mean `healthcheck`?" in err


def test_wrong_type(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d["services"]["driver"].update(devices="motor"))
    code, _, err = lab_run(capsys, lab, "check")   # a load error: nothing to check, reported like validate
    assert code == 2 and "services.driver.devices: must be a list of logical device names" in err


def test_missing_ros_domain_id(capsys: pytest.CaptureFixture, lab: Path) -> None:
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("          ros_domain_id: 2\n", ""))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "hosts.yml" in err and "ros_domain_id" in err


def test_service_asking_for_an_undeclared_device(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d["services"]["driver"].update(devices=["motor", "lidar"]))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2
    assert "services.driver.devices[1]: service 'driver' needs device `lidar`" in err
    assert "'r1', 'r2'" in err and "`lidar: /dev/robot/lidar` under their `devices:`" in err
    code, _, err = lab_run(capsys, lab, "render", "--out", str(lab / "out"))
    assert code == 2 and "needs device `lidar`" in err and not (lab / "out").exists()


def test_template_error_names_template_file_and_line(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "logrotate.conf.j2").write_text("# logs\n\n{{ no_such_variable }}\n")
    edit(lab / "fleet.yml", lambda d: d.update(templates="./templates"))
    for command in ("validate", "check"):
        code, out, err = lab_run(capsys, lab, command)
        assert code == 2 and "logrotate.conf.j2:3" in out + err and "no_such_variable" in out + err
    code, _, err = lab_run(capsys, lab, "render", "--out", str(lab / "out"))
    assert code == 2 and "logrotate.conf.j2:3" in err


def test_a_broken_template_stops_apply_but_not_an_emergency_rollback(capsys: pytest.CaptureFixture,
                                                                     lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "logrotate.conf.j2").write_text("{{ no_such_variable }}\n")
    edit(lab / "fleet.yml", lambda d: d.update(templates="./templates"))
    code, _, err = lab_run(capsys, lab, "apply", "--yes")
    assert code == 2 and "logrotate.conf.j2" in err
    # rollback goes to the releases kept on the robots: it reaches for them (none answer here)
    code, out, err = lab_run(capsys, lab, "rollback", "--yes")
    assert code == 3 and "logrotate.conf.j2" not in out + err
    assert "unreachable" in out or "host key" in out


def test_template_syntax_error(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text("services:\n{% for x in %}\n")
    edit(lab / "fleet.yml", lambda d: d.update(templates="./templates"))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "compose.yml.j2:2" in err and "syntax" in err


def test_overridden_template_is_held_to_the_checklist(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text(
        "services:\n{% for svc in services %}\n  {{ svc.name }}:\n    image: {{ svc.image | compose_str }}\n"
        "    environment: {ROS_DOMAIN_ID: '${ROS_DOMAIN_ID}'}\n    network_mode: host\n{% endfor %}\n")
    edit(lab / "fleet.yml", lambda d: d.update(templates="./templates"))
    code, out, err = lab_run(capsys, lab, "check")
    assert code == 2
    for rule in ("restart-missing", "log-rotation-missing", "shm-too-small", "resources-missing"):
        assert f"[{rule}]" in err + out
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "restart" in err and "resources-missing" not in err   # validate: errors only


def test_wrong_vault_password(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "wrong").write_text("not-the-password\n")
    code, _, err = run(capsys, "validate", str(lab / "fleet.yml"), "--vault-password-file", str(lab / "wrong"))
    assert code == 2 and "vault.yml" in err and "password" in err


@pytest.mark.parametrize("field, value, key", [
    ("project", "lab; reboot", "project"),
    ("version", "1.0$(reboot)", "version"),
    ("deploy_root", "~/x`reboot`", "deploy_root"),
    ("version", "1.0\nreboot", "version"),
])
def test_values_that_would_reach_a_shell(capsys: pytest.CaptureFixture, lab: Path, field: str, value: str,
                                         key: str) -> None:
    edit(lab / "fleet.yml", lambda d: d.update({field: value}))
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and "fleet.yml:" in err and f" {key}: " in err


def test_newline_in_an_environment_value(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d["services"]["driver"].update(environment={"MOTD": "a\nb"}))
    code, _, err = lab_run(capsys, lab, "check")
    assert code == 2 and "services.driver.environment.MOTD: value contains a newline" in err


def test_every_problem_is_reported_at_once(capsys: pytest.CaptureFixture, lab: Path) -> None:
    def break_it(d: dict) -> None:
        d["version"] = "latest"
        d["services"]["driver"]["image"] = "lab/driver:1.0"
        d["rollout"] = {"forks": 0}
    edit(lab / "fleet.yml", break_it)
    code, _, err = lab_run(capsys, lab, "validate")
    assert code == 2 and err.count("error: ") == 3


def test_check_reports_severity_rule_and_fix(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab / "fleet.yml", lambda d: d["services"]["driver"].update(privileged=True))
    code, out, err = lab_run(capsys, lab, "check", "--json")
    assert code == 2
    finding = next(f for f in json.loads(out)["findings"] if f["rule"] == "privileged")
    assert finding["severity"] == "error" and finding["key"] == "services.driver.privileged"
    assert finding["line"] and "allow_privileged" in finding["fix"]
    code, out, err = lab_run(capsys, lab, "check")
    assert "error[privileged] " in out and "FAIL" in out


def test_validate_json(capsys: pytest.CaptureFixture, lab: Path) -> None:
    code, out, _ = lab_run(capsys, lab, "validate", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["ok"] and doc["project"] == "lab" and doc["robots"] == ["r1", "r2"]
    assert [p["rule"] for p in doc["problems"]] == ["gpu-unavailable"]
