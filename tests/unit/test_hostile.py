"""Hostile and unusual input (issue 18): every case is refused cleanly or handled, never a crash or a hang.

Each refusal asserts the exit code, where the message points (file:line or key), that no
traceback or internal error appears, and that nothing was written. The sandbox cases also
assert that no command ran (a marker file), and that no environment value reached any output.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Callable

import paramiko
import pytest
import yaml

from rosdeploy import yamlsrc
from rosdeploy.cli import main
from rosdeploy.errors import InputError, RenderError
from rosdeploy.render import Renderer
from rosdeploy.transport import RevokedHostKey, _RejectUnknown, parse_known_hosts
from test_render import make_host, make_service, make_spec

DATA = Path(__file__).resolve().parent / "data" / "fleet"
CANARY = "canary-env-value-5c1e9a"
VAULT_CANARY = "vault-password-canary-77d2"
LAB_SECRET = "unit-test-token-7d1e"


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    shutil.copytree(DATA, tmp_path / "lab")
    monkeypatch.setenv("ROSDEPLOY_CANARY", CANARY)
    monkeypatch.setenv("ROSDEPLOY_VAULT_PASSWORD", VAULT_CANARY)   # the file below wins; it must never show
    monkeypatch.delenv("ROSDEPLOY_VAULT_PASSWORD_FILE", raising=False)
    return tmp_path / "lab"


def cli(capsys: pytest.CaptureFixture, lab: Path, command: str, *argv: str) -> tuple[int, str]:
    password = str(lab / "inventory" / ".vault-password")
    extra = ["--out", str(lab / "out")] if command == "render" else []
    code = main([command, str(lab / "fleet.yml"), "--vault-password-file", password, *extra, *argv])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text and "internal error" not in text, text
    for secret in (CANARY, VAULT_CANARY, LAB_SECRET):
        assert secret not in text
    return code, text


def edit(lab: Path, change: Callable[[dict], None]) -> None:
    path = lab / "fleet.yml"
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def set_env(value: str) -> Callable[[dict], None]:
    return lambda d: d["services"]["driver"].setdefault("environment", {}).update(X=value)


def refused_everywhere(capsys: pytest.CaptureFixture, lab: Path, *expect: str,
                       commands: tuple[str, ...] = ("validate", "check", "render")) -> None:
    for command in commands:
        code, text = cli(capsys, lab, command)
        assert code == 2, (command, text)
        for part in expect:
            assert part in text, (command, part, text)
        assert not (lab / "out").exists(), f"{command} wrote files"


# ------------------------------------------------------------------- 1. sandbox

MARKER = "{marker}"
SANDBOX_ESCAPES = [
    "{{ lipsum.__globals__['os'].system('touch MARKER') }}",
    "{{ lipsum.__globals__.os.popen('touch MARKER').read() }}",
    "{{ cycler.__init__.__globals__.os.system('touch MARKER') }}",
    "{{ joiner.__init__.__globals__.os.environ }}",
    "{{ namespace.__init__.__globals__.os.environ }}",
    "{{ self.__init__.__globals__.__builtins__.open('MARKER', 'w') }}",
    "{{ self._TemplateReference__context.cycler.__init__.__globals__.os.system('touch MARKER') }}",
    "{{ ''.__class__.__mro__[1].__subclasses__() }}",
    "{{ ().__class__.__base__.__subclasses__() }}",
    "{{ range.__class__ }}",
    "{{ ''|attr('__class__')|attr('__mro__') }}",
    "{{ (''|attr('\\x5f\\x5fclass\\x5f\\x5f')) }}",
    "{{ '{0.__class__.__mro__}'.format('') }}",
    "{{ '{0.__globals__}'.format(lipsum) }}",
    "{{ '%s'|format(lipsum.__globals__) }}",
    "{{ dict.__init__ }}",
    "{{ host.__class__.__init__.__globals__ }}",
    "{{ vars.__class__ }}",
    "{{ [].append(1) }}",
    "{{ {}.update(a=1) }}",
    "{{ 'a' * 100000000 }}",
    "{{ [1, 2] * 100000000 }}",
    "{{ 9 ** 9999999 }}",
    "{{ (9 ** 99) ** 99 ** 9 }}",
    "{{ '%999999999s' % 'a' }}",
    "{{ '{:>999999999}'.format('a') }}",
    "{{ 'a'|center(999999999) }}",
    "{{ 'a'|indent(999999999) }}",
    "{{ '%999999999d'|format(1) }}",
    "{{ range(100000000)|list }}",
    "{{ 1 / 0 }}",
    "{{ undefined_thing.x }}",
    "{% for i in range(100000) %}{% for j in range(100000) %}x{% endfor %}{% endfor %}",
    "{% include 'compose.yml.j2' %}",
    "{% import 'env.j2' as e %}{{ e }}",
    "{% macro f() %}{{ f() }}{% endmacro %}{{ f() }}",
    "{{ vars.api_token }}",                  # a vault secret copied into compose.yml
]


@pytest.mark.parametrize("payload", SANDBOX_ESCAPES)
def test_fleet_value_cannot_escape_the_sandbox(capsys: pytest.CaptureFixture, lab: Path, payload: str) -> None:
    marker = lab.parent / "MARKER"
    edit(lab, set_env(payload.replace("MARKER", str(marker))))
    refused_everywhere(capsys, lab, "fleet.yml", "services.driver.environment.X")
    assert not marker.exists()


@pytest.mark.parametrize("payload", ["{{ host.vars }}", "{{ vars }}", "{{ host }}", "{{ host.vars.items()|list }}",
                                     "{{ vars|dictsort }}", "{{ host.secret_values }}"])
def test_a_value_that_dumps_the_vars_leaks_no_secret(capsys: pytest.CaptureFixture, lab: Path, payload: str) -> None:
    """Refused (the secret would reach compose.yml) or harmless (the vars print as a summary)."""
    edit(lab, set_env(payload))
    code, text = cli(capsys, lab, "render")   # cli() asserts no secret or canary in the output
    assert code in (0, 2), text
    written = [f for f in (lab / "out").rglob("*") if f.is_file() and f.name != ".env"] if code == 0 else []
    for f in written:
        content = f.read_text()
        assert LAB_SECRET not in content and CANARY not in content and VAULT_CANARY not in content, f


@pytest.mark.parametrize("payload", [
    "{{ lipsum.__globals__['os'].system('touch MARKER') }}",
    "{{ cycler.__init__.__globals__.os.environ }}",
    "{{ self.__init__ }}",
    "{{ 9 ** 9999999 }}",
    "{{ (9 ** 99) ** 99 ** 9 }}",
    "{{ 1 / 0 }}",
    "{% macro f() %}{{ f() }}{% endmacro %}{{ f() }}",
])
def test_template_folder_cannot_escape_the_sandbox(capsys: pytest.CaptureFixture, lab: Path, payload: str) -> None:
    marker = lab.parent / "MARKER"
    (lab / "templates").mkdir()
    (lab / "templates" / "logrotate.conf.j2").write_text("# x\n" + payload.replace("MARKER", str(marker)) + "\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    refused_everywhere(capsys, lab, "logrotate.conf.j2:2")
    assert not marker.exists()


def test_expressions_and_if_still_work_in_values(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env("{% if inventory_hostname == 'r1' %}one{% else %}{{ inventory_hostname | upper }}{% endif %}"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert '"one"' in (lab / "out" / "r1" / "compose.yml").read_text()
    assert '"R2"' in (lab / "out" / "r2" / "compose.yml").read_text()


# ------------------------------------------------- 2. one validation, every command

def dup_domain(lab: Path) -> None:
    path = lab / "inventory" / "hosts.yml"
    path.write_text(path.read_text().replace("ros_domain_id: 2", "ros_domain_id: 1"))


def privileged(lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(privileged=True))


def docker_socket(lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(volumes=["/var/run/docker.sock:/var/run/docker.sock"]))


@pytest.mark.parametrize("breakage, rule", [(dup_domain, "domain-id-duplicate"), (privileged, "privileged"),
                                            (docker_socket, "docker-socket-mounted")])
def test_an_error_finding_blocks_every_command(capsys: pytest.CaptureFixture, lab: Path,
                                               breakage: Callable[[Path], None], rule: str) -> None:
    breakage(lab)
    code, text = cli(capsys, lab, "check")
    assert code == 2 and f"[{rule}]" in text
    refused_everywhere(capsys, lab, commands=("validate", "render"))
    for command in (("plan",), ("apply", "--yes")):   # refused before any robot is contacted
        code, text = cli(capsys, lab, *command)
        assert code == 2, text
        assert "unreachable" not in text and "host key" not in text


@pytest.mark.parametrize("change, rule, words", [
    ({"volumes": ["/var/run:/hostrun"]}, "docker-socket-mounted", "mounts /var/run, which holds the engine socket"),
    ({"volumes": ["/run:/r:ro"]}, "docker-socket-mounted", "mounts /run, which holds"),
    ({"volumes": ["/run/containerd/containerd.sock:/c.sock"]}, "docker-socket-mounted", "containerd.sock"),
    ({"compose": {"pid": "host"}}, "privileged", "(pid: host)"),
    ({"compose": {"userns_mode": "host"}}, "privileged", "(userns_mode: host)"),
    ({"compose": {"cap_add": ["ALL"]}}, "privileged", "adds ALL"),
    ({"compose": {"cap_add": ["cap_sys_admin"]}}, "privileged", "adds SYS_ADMIN"),
    ({"compose": {"security_opt": ["seccomp:unconfined"]}}, "privileged", "turns off confinement"),
    ({"compose": {"device_cgroup_rules": ["a *:* rwm"]}}, "privileged", "every device"),
])
def test_privilege_piece_by_piece_is_privilege(capsys: pytest.CaptureFixture, lab: Path, change: dict, rule: str,
                                               words: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(change))
    code, text = cli(capsys, lab, "check")
    assert code == 2 and f"[{rule}]" in text and words in text, text
    edit(lab, lambda d: d["services"]["driver"].update(allow_privileged=True))
    code, text = cli(capsys, lab, "check")
    assert f"[{rule}]" not in text, text


@pytest.mark.parametrize("key", ["volumes_from", "extends", "container_name"])
def test_compose_keys_that_bring_in_what_check_never_sees_are_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                                      key: str) -> None:
    value = {"volumes_from": ["bridge"], "extends": {"file": "/etc/evil.yml", "service": "x"},
             "container_name": "../x"}[key]
    edit(lab, lambda d: d["services"]["driver"].update(compose={key: value}))
    refused_everywhere(capsys, lab, f"compose.{key}")


def test_allow_privileged_waives_privileged(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(privileged=True, allow_privileged=True))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text


# ------------------------------------------------------ 3. no crash, no hang

BOMB = "lol: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"l{i}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(9))


def fleet_text(lab: Path, text: str) -> None:
    (lab / "fleet.yml").write_text(text)


def fleet_append(text: str) -> Callable[[Path], None]:
    return lambda lab: (lab / "fleet.yml").write_text((lab / "fleet.yml").read_text() + text)


def fleet_bytes(data: bytes) -> Callable[[Path], None]:
    return lambda lab: (lab / "fleet.yml").write_bytes((lab / "fleet.yml").read_bytes() + data)


def vars_file(text: str) -> Callable[[Path], None]:
    return lambda lab: (lab / "inventory" / "group_vars" / "all" / "extra.yml").write_text(text)


def fleet_key(change: Callable[[dict], None]) -> Callable[[Path], None]:
    return lambda lab: edit(lab, change)


MALFORMED = {
    # name: (breakage, what the message must name)
    "alias bomb in the fleet file": (fleet_append("vars:\n  " + BOMB.replace("\n", "\n  ")), "fleet.yml:"),
    "alias bomb in a vars file": (vars_file(BOMB), "extra.yml:"),
    "merge-key bomb": (fleet_append("x-a: &m0 {k: 1}\n" + "".join(
        f"x-{i}: &m{i + 1} {{<<: [*m{i}], l{i}: [{', '.join(['*m' + str(i)] * 9)}]}}\n" for i in range(10))),
        "fleet.yml:"),
    "recursive alias": (fleet_append("vars: {loop: &l [1, *l]}\n"), "fleet.yml:23:"),
    "recursive alias in a vars file": (vars_file("a: &a {b: *a}\n"), "extra.yml:1:"),
    "mutually recursive aliases": (fleet_append("vars: {a: &a [1, &b [*a, *b]]}\n"), "fleet.yml:23:"),
    "non-UTF-8 byte": (fleet_bytes(b"# caf\xe9 " + LAB_SECRET.encode() + b"\n"), "fleet.yml:23:"),
    "NUL byte": (fleet_bytes(b"x: \x00\n"), "fleet.yml:23:"),
    "deep flow nesting": (fleet_append("vars: {deep: " + "[" * 50000 + "]" * 50000 + "}\n"), "fleet.yml:23:"),
    "deep block nesting": (fleet_append("vars:\n" + "".join(" " * (i + 2) + f"k{i}:\n" for i in range(400))),
                           "fleet.yml:"),
    "deep dashes": (fleet_append("vars: {x: 1}\nx-list:\n" + "- " * 3000 + "x\n"), "fleet.yml:25:"),
    "deep nesting in a vars file": (vars_file("a: " + "{b: " * 5000 + "1" + "}" * 5000), "extra.yml:1:"),
    "complex mapping key": (fleet_append("? [a, b]\n: 1\n"), "fleet.yml:23:"),
    "python tag": (fleet_append("vars: {x: !!python/object/apply:os.system [id]}\n"), "fleet.yml:23:"),
    "two documents": (fleet_append("---\nproject: other\n"), "fleet.yml:23:"),
    "tab indentation": (fleet_append("vars:\n\tx: 1\n"), "fleet.yml:24:"),
    "empty file": (lambda lab: fleet_text(lab, ""), "fleet.yml"),
    "a list, not a mapping": (lambda lab: fleet_text(lab, "- a\n- b\n"), "fleet.yml"),
    "duplicate key": (fleet_append("project: again\n"), "fleet.yml:23:"),
    "unicode digit max_file": (fleet_key(lambda d: d.update(logging={"max_file": "²"})), "logging.max_file"),
    "unicode digit forks": (fleet_key(lambda d: d.update(rollout={"forks": "١"})), "rollout.forks"),
    "unicode digit wave": (fleet_key(lambda d: d.update(rollout={"waves": ["²%"]})), "rollout.waves[0]"),
    "arabic digit wave": (fleet_key(lambda d: d.update(rollout={"waves": ["٥٠%"]})), "rollout.waves[0]"),
    "unicode digit duration": (fleet_key(lambda d: d.update(health={"timeout": "١٠s"})), "health.timeout"),
    "superscript duration": (fleet_key(lambda d: d.update(health={"timeout": "²"})), "health.timeout"),
    "unicode digit size": (fleet_key(lambda d: d.update(ros={"shm_size": "٥١٢m"})), "ros.shm_size"),
    "unicode digit memory": (fleet_key(lambda d: d["services"]["driver"].update(resources={"memory": "²m"})),
                             "services.driver.resources.memory"),
    "inventory path too long": (fleet_key(lambda d: d.update(inventory="x" * 5000)), "inventory"),
    "templates path too long": (fleet_key(lambda d: d.update(templates="x" * 5000)), "templates"),
    "huge number": (fleet_append("preflight: {min_free_disk_mb: " + "9" * 5000 + "}\n"), "preflight"),
    "float overflow": (fleet_key(lambda d: d["services"]["driver"].update(resources={"cpus": float("inf")})),
                       "services.driver.resources.cpus"),
    # a control character is refused once, at its key; what the converter then makes of the
    # value (no further message under that key) must not crash it
    "newline in a window's duration": (fleet_key(lambda d: d.update(
        window={"days": ["mon"], "start": "01:00", "duration": "x\ny"})), "window.duration"),
    "newline in a ready timing": (fleet_key(lambda d: d.update(
        ready={"interval": "1\n0s", "when": [{"lock": "/var/lib/x.lock"}]})), "ready.interval"),
    "a files var whose template fails": (lambda lab: (
        fleet_key(lambda d: (d.update(files={"cal": {"var": "calibration", "target": "/config/cal.yaml"}}),
                             d["services"]["driver"].update(files=["cal"])))(lab),
        vars_file("calibration: '{{ 1/0 }}'\n")(lab)), "extra.yml:1: calibration"),
}


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_malformed_input_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path, name: str) -> None:
    breakage, where = MALFORMED[name]
    breakage(lab)
    refused_everywhere(capsys, lab, where)


def test_non_utf8_message_does_not_dump_the_file(capsys: pytest.CaptureFixture, lab: Path) -> None:
    fleet_bytes(b"# caf\xe9\n")(lab)
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "0xe9" in text and "not UTF-8" in text
    assert "registry.local" not in text and "b'" not in text


def test_yamlsrc_bounds_apply_to_every_caller() -> None:
    with pytest.raises(InputError, match="alias bomb"):
        yamlsrc.load("x.yml", BOMB)
    with pytest.raises(InputError, match="alias bomb"):
        yamlsrc.load_data(BOMB)
    with pytest.raises(InputError, match="nested more than"):
        yamlsrc.load_data("[" * 100000)
    with pytest.raises(InputError, match="contains itself"):
        yamlsrc.load_data("&x [*x]")
    # a normal file with anchors, aliases and merges still loads, lines and all
    doc = yamlsrc.load("x.yml", "base: &b {a: 1, b: [1, 2]}\nuse:\n  <<: *b\n  c: *b\n")
    assert doc.data["use"] == {"a": 1, "b": [1, 2], "c": {"a": 1, "b": [1, 2]}}
    assert doc.line(("use", "c")) == 4


def test_checks_of_a_user_compose_template_with_an_alias_bomb(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "compose.yml.j2").write_text(BOMB + "services: {}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "check")
    assert code == 2 and "compose-invalid" in text and "alias bomb" in text


# --------------------------------------------------- 4. refused values

REFUSED = {
    "deploy_root .. in the middle": ({"deploy_root": "/opt/x/../../etc"}, "deploy_root"),
    "deploy_root ~/..": ({"deploy_root": "~/../../etc"}, "deploy_root"),
    "deploy_root trailing ..": ({"deploy_root": "/opt/rosdeploy/.."}, "deploy_root"),
    "deploy_root command substitution": ({"deploy_root": "/opt/$(id)"}, "deploy_root"),
    "deploy_root backticks": ({"deploy_root": "/opt/`id`"}, "deploy_root"),
    "deploy_root semicolon": ({"deploy_root": "/opt/x;rm -rf /"}, "deploy_root"),
    "deploy_root relative": ({"deploy_root": "rosdeploy"}, "deploy_root"),
    "deploy_root other user's home": ({"deploy_root": "~root/x"}, "deploy_root"),
}
SERVICE_REFUSED = {
    "compose typo": ({"compose": {"cap_ad": ["SYS_NICE"]}}, "did you mean 'cap_add'?"),
    "compose unknown key": ({"compose": {"frobnicate": 1}}, "services.driver.compose.frobnicate"),
    "compose wrong type": ({"compose": {"cap_add": "SYS_NICE"}}, "services.driver.compose.cap_add"),
    "compose bad nested": ({"compose": {"ulimits": {"nofile": {"soft": "x"}}}}, "services.driver.compose.ulimits"),
    "compose read_only string": ({"compose": {"read_only": "yes"}}, "services.driver.compose.read_only"),
    "compose managed key": ({"compose": {"privileged": True}}, "services.driver.compose.privileged"),
    "memory 0m": ({"resources": {"memory": "0m"}}, "services.driver.resources.memory"),
    "memory 1k": ({"resources": {"memory": "1k"}}, "services.driver.resources.memory"),
    "memory negative": ({"resources": {"memory": "-1m"}}, "services.driver.resources.memory"),
    "image name of 4096 characters": ({"image": "lab/" + "a" * 4092}, "services.driver.image: the image name"),
    "compose secret never defined": ({"compose": {"secrets": ["token"]}}, "services.driver.compose.secrets[0]"),
    "compose config never defined": ({"compose": {"configs": [{"source": "c"}]}}, "services.driver.compose.configs"),
}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_fleet_values(capsys: pytest.CaptureFixture, lab: Path, name: str) -> None:
    change, key = REFUSED[name]
    edit(lab, lambda d: d.update(change))
    refused_everywhere(capsys, lab, "fleet.yml:", key)


@pytest.mark.parametrize("name", sorted(SERVICE_REFUSED))
def test_refused_service_values(capsys: pytest.CaptureFixture, lab: Path, name: str) -> None:
    change, expect = SERVICE_REFUSED[name]
    edit(lab, lambda d: d["services"]["driver"].update(change))
    refused_everywhere(capsys, lab, "fleet.yml:", expect)


@pytest.mark.parametrize("peers", [["a<b>"], ["10.0.0.1; rm -rf /"], ["-oProxyCommand=x"], ["a b"], [""],
                                   ["x" * 300], ["10.0.0.1", "bad/peer"], ["256.1.1.1"], ["10.0.0"]])
def test_dds_peers_must_be_addresses(capsys: pytest.CaptureFixture, lab: Path, peers: list) -> None:
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(yaml.safe_dump({"dds_peers": peers}))
    refused_everywhere(capsys, lab, "dds_peers")


def test_good_dds_peers_and_compose_keys_pass(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r2.yml").write_text(
        yaml.safe_dump({"dds_peers": ["10.0.0.7", "amr-3.fleet.local", "fd00::7"]}))
    edit(lab, lambda d: d["services"]["driver"].update(
        compose={"cap_add": ["SYS_NICE"], "ulimits": {"rtprio": 99}, "x-note": "ok", "stop_grace_period": "5s"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text


def test_dollar_in_compose_values_is_literal_unless_asked(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(compose={"hostname": "$HOSTNAME", "working_dir": "/a${B}"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    svc = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]
    assert (svc["hostname"], svc["working_dir"]) == ("$$HOSTNAME", "/a$${B}")
    shutil.rmtree(lab / "out")
    edit(lab, lambda d: d["services"]["driver"].update(compose_interpolate=True))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    svc = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]
    assert (svc["hostname"], svc["working_dir"]) == ("$HOSTNAME", "/a${B}")


def test_rendered_compose_with_extras_is_valid_for_compose_v1(lab: Path, capsys: pytest.CaptureFixture) -> None:
    """The schema refusals match what Compose v1 itself accepts (when it is installed: host-setup does)."""
    if shutil.which("docker-compose") is None:
        pytest.skip("docker-compose (v1) is installed by scripts/host-setup")
    edit(lab, lambda d: d["services"]["driver"].update(compose={"cap_add": ["SYS_NICE"], "hostname": "$x"}))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    release = lab / "out" / "r1"
    done = subprocess.run(["docker-compose", "-f", str(release / "compose.yml"), "config", "-q"],
                          cwd=release, capture_output=True, text=True, env={**os.environ, "ROS_DOMAIN_ID": "1"})
    assert done.returncode == 0, done.stderr


# ----------------------------------------------------- 5. messages point at the cause

def test_secret_in_environment_is_reported_at_the_fleet_key(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env("token={{ api_token }}"))
    code, text = cli(capsys, lab, "validate")
    assert code == 2
    assert "fleet.yml:" in text and "services.driver.environment.X" in text and "secrets:" in text
    assert "hosts.yml" not in text


def test_robot_names_are_quoted_on_one_line() -> None:
    spec = make_spec(make_service(environment={"X": "{{ missing }}"}))
    with pytest.raises(RenderError) as caught:
        Renderer(spec).render(make_host(name="evil\nerror: fake"))
    message = str(caught.value)
    assert "\n" not in message and "robot 'evil\\nerror: fake'" in message


# ------------------------------------------------------ 6. SSH host certificates

@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[str]]:
    """Real keys from ssh-keygen (installed with openssh by scripts/host-setup): a CA, a host key
    it certified, and an unrelated old key."""
    if shutil.which("ssh-keygen") is None:
        pytest.skip("ssh-keygen is installed by scripts/host-setup (openssh)")
    folder = tmp_path_factory.mktemp("keys")
    for name, kind in (("ca", "ed25519"), ("host", "ed25519"), ("old", "ecdsa")):
        subprocess.run(["ssh-keygen", "-q", "-t", kind, "-N", "", "-f", str(folder / name)], check=True)
    subprocess.run(["ssh-keygen", "-q", "-s", str(folder / "ca"), "-I", "amr1", "-h", "-n", "amr1",
                    str(folder / "host.pub")], check=True)
    out = {name: (folder / f"{name}.pub").read_text().split()[:2] for name in ("ca", "host", "old", "host-cert")}
    out["folder"] = [str(folder)]
    return out


def test_cert_authority_line_is_skipped_with_a_warning(keys: dict) -> None:
    lines = [f"@cert-authority *.fleet {' '.join(keys['ca'])}", f"amr1 {' '.join(keys['host'])}",
             "garbage", f"amr4 {' '.join(keys['host-cert'])}"]
    known = parse_known_hosts(lines, "kh")
    assert [(k.get_name(), k.get_base64()) for k in known.keys_for("amr1")] == [tuple(keys["host"])]
    assert known.keys_for("amr4") == []
    assert any("@cert-authority" in w and "cannot verify" in w for w in known.warnings)
    assert any("line(s) 3, 4" in w for w in known.warnings)


def test_revoked_key_is_never_trusted_and_named(keys: dict) -> None:
    lines = [f"amr2,amr3 {' '.join(keys['old'])}", f"@revoked * {' '.join(keys['old'])}",
             f"amr1 {' '.join(keys['host'])}"]
    known = parse_known_hosts(lines, "kh")
    assert known.keys_for("amr2") == []
    assert known.keys_for("amr1")
    old = paramiko.PKey.from_path(Path(keys["folder"][0]) / "old")
    with pytest.raises(RevokedHostKey, match="@revoked"):
        _RejectUnknown([known]).missing_host_key(paramiko.SSHClient(), "amr2", old)
    host = paramiko.PKey.from_path(Path(keys["folder"][0]) / "host")
    with pytest.raises(paramiko.SSHException, match="not found in known_hosts"):
        _RejectUnknown([known]).missing_host_key(paramiko.SSHClient(), "amr9", host)


def test_status_with_a_cert_authority_known_hosts_does_not_crash(capsys: pytest.CaptureFixture, lab: Path,
                                                                 keys: dict) -> None:
    known_hosts = lab / "known_hosts"
    known_hosts.write_text(f"@cert-authority * {' '.join(keys['ca'])}\n@revoked * {' '.join(keys['old'])}\n")
    edit(lab, lambda d: d.update(ssh={"known_hosts": str(known_hosts), "connect_timeout": "1s", "persist": 0}))
    for address in ("127.0.0.1", "127.0.0.2"):   # nothing listens on port 1: unreachable, not a crash
        path = lab / "inventory" / "hosts.yml"
        path.write_text(path.read_text().replace(f"ansible_host: {address}", f"ansible_host: {address}\n"
                                                                             "          ansible_port: 1"))
    code, text = cli(capsys, lab, "status")
    assert code == 3, text


@pytest.mark.parametrize("key, value", [("templates", "$ROSDEPLOY_CANARY/t"), ("inventory", "${ROSDEPLOY_CANARY}"),
                                        ("templates", "$ROSDEPLOY_VAULT_PASSWORD"),
                                        ("inventory", "/x/${ROSDEPLOY_VAULT_PASSWORD}")])
def test_environment_values_in_paths_never_reach_a_message(capsys: pytest.CaptureFixture, lab: Path, key: str,
                                                            value: str) -> None:
    edit(lab, lambda d: d.update({key: value}))
    refused_everywhere(capsys, lab, "fleet.yml:", key)   # cli() asserts neither value is printed


def test_a_template_linking_outside_its_folder_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    secret = lab.parent / "id_ed25519"
    secret.write_text("PRIVATE KEY canary-key-material\n")
    (lab / "templates" / "stolen.j2").symlink_to(secret)
    edit(lab, lambda d: d.update(templates="./templates"))
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "outside the template folder" in text and "canary-key-material" not in text
    assert not (lab / "out").exists()


def test_a_template_that_is_not_utf8_is_a_clean_error(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "logrotate.conf.j2").write_bytes(b"# ok\n# caf\xe9\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    refused_everywhere(capsys, lab, "logrotate.conf.j2:2", "not UTF-8")


@pytest.mark.parametrize("path", ["/dev/zero", "/dev/null", "/", "/nonexistent/fleet.yml", "/tmp/" + "x" * 5000])
def test_a_fleet_path_that_is_no_file(capsys: pytest.CaptureFixture, path: str) -> None:
    code = main(["validate", path])
    text = "".join(capsys.readouterr())
    shown = path if len(path) < 200 else path[:60]      # a 5,000-character path is cut short in messages
    assert code == 2 and shown in text and "Traceback" not in text and "internal error" not in text


def test_hashed_and_bracketed_entries_still_verify(keys: dict, tmp_path: Path) -> None:
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text(f"amr1 {' '.join(keys['host'])}\n[10.0.0.5]:2222 {' '.join(keys['host'])}\n"
                           f"@cert-authority * {' '.join(keys['ca'])}\n")
    subprocess.run(["ssh-keygen", "-H", "-f", str(known_hosts)], check=True, capture_output=True)
    known = parse_known_hosts(known_hosts.read_text().splitlines(), str(known_hosts))
    assert "amr1" not in known_hosts.read_text()     # really hashed
    assert known.keys_for("amr1") and known.keys_for("[10.0.0.5]:2222")
    assert known.keys_for("amr2") == []


@pytest.mark.parametrize("name, why", [
    # deploy._tarball adds its own: the release would carry two members of that name
    ("manifest.json", "is written by rosdeploy into every release (version"),
    ("images.txt", "is written by rosdeploy into every release (version"),
    # a built-in output under another template's name: one of the two was silently dropped
    (".env", "is written by rosdeploy into every release, from env.j2: to replace it, name this template env.j2"),
    ("99-rosdeploy.rules", "is written by rosdeploy into every release, from udev.rules.j2: to replace it, "
                           "name this template udev.rules.j2"),
    # the release's folders: validate said OK, and render failed on "--out: Not a directory"
    ("store", "is a folder of every release"),
    ("files", "is a folder of every release"),
])
def test_a_template_cannot_take_a_name_the_release_already_has(capsys: pytest.CaptureFixture, lab: Path,
                                                               name: str, why: str) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / f"{name}.j2").write_text("{}\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    refused_everywhere(capsys, lab, f"templates/{name}.j2: {name} {why}")
    assert not (lab / "out").exists()


@pytest.mark.parametrize("argv, option", [(["rollback", "F", "--to", "../../x"], "--to"),
                                          (["apply", "F", "--order-by", "a b"], "--order-by")])
def test_command_line_words_that_reach_robots_are_checked_first(argv: list[str], option: str) -> None:
    from rosdeploy.cli import build_parser
    from rosdeploy.cli.common import UsageError
    with pytest.raises(UsageError, match=f"argument {option}: "):
        build_parser().parse_args(argv)


@pytest.mark.parametrize("where", ["host_vars/r2.yml", "group_vars/lab.yml"])
def test_a_duplicate_domain_id_is_reported_where_the_id_was_set(capsys: pytest.CaptureFixture, lab: Path,
                                                                where: str) -> None:
    hosts = lab / "inventory" / "hosts.yml"     # r2 gets its ID from a vars file, not from hosts.yml
    hosts.write_text(hosts.read_text().replace("ros_domain_id: 2", "ansible_port: 22"))
    path = lab / "inventory" / where
    path.parent.mkdir(exist_ok=True)
    path.write_text("motd: hello\nros_domain_id: 1\n")
    code, text = cli(capsys, lab, "check")
    assert code == 2 and f"{path}:2: ros_domain_id: 'r2' and 'r1' ({hosts}:8) both use ros_domain_id 1" in text, text


def test_a_vault_tag_in_the_fleet_file_is_refused_not_written_out(capsys: pytest.CaptureFixture, lab: Path) -> None:
    fleet = lab / "fleet.yml"     # rendered `X: "garbage"`, ciphertext or not, as plain text before
    fleet.write_text(fleet.read_text().replace("services:\n", "vars:\n  token: !vault garbage\nservices:\n", 1))
    refused_everywhere(capsys, lab, "vars.token: a `!vault` value is decrypted only in the inventory's vars files")
