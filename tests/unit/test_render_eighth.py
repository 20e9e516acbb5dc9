"""Eighth round, rendering (probes I, J and K): what the renderer writes, refuses and says.

K3  an env.j2 override's error quoted values computed from `secrets`.
K5  an ansible_user computed from a vault var reached logrotate.conf through the default home.
J3  logrotate.conf ignored the robot's own rosdeploy_deploy_root.
K9  a null secret became `API_TOKEN=None`; an empty one passed, and compose refused it on the robot.
K11 the leak-scan refusal named no vault var and reported the store copy again.
J4  Compose v1 expanded `${..}` inside a single-quoted .env value.
K6  a secret file's content address was the unsalted sha256 of the secret.
I4/I5 a template override that is no regular file was ignored; template files had no size bound.
I11 a failed include said only the partial's name.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

import test_hostile
from test_hostile import LAB_SECRET, cli, edit
from test_vault_taint import vault_file

lab = test_hostile.lab      # the fixture: the example fleet copied, its vault password in place

BUILTIN_ENV = (Path(__file__).resolve().parents[2] / "rosdeploy" / "templates" / "env.j2").read_text()
REVERSED = LAB_SECRET[::-1]


def templates(lab: Path, **files: str) -> Path:
    """A template folder beside the fleet file, with `files` (name -> text; `__` for `.`)."""
    folder = lab / "templates"
    folder.mkdir(exist_ok=True)
    for name, text in files.items():
        (folder / name.replace("__", ".")).write_text(text)
    edit(lab, lambda d: d.update(templates="./templates"))
    return folder


def host_vars(lab: Path, **values: object) -> None:
    path = lab / "inventory" / "host_vars" / "r1.yml"
    data = yaml.safe_load(path.read_text()) or {}
    data.update(values)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def refused(capsys: pytest.CaptureFixture, lab: Path, *expect: str, hidden: tuple[str, ...] = (),
            commands: tuple[str, ...] = ("validate", "render")) -> str:
    text = ""
    for command in commands:
        code, text = cli(capsys, lab, command)      # cli(): no traceback, and LAB_SECRET not shown
        assert code == 2, (command, text)
        for part in expect:
            assert part in text, (command, part, text)
        for secret in hidden:
            assert secret not in text, (command, secret, text)
        assert not (lab / "out").exists(), f"{command} wrote files"
    return text


# ------------------------------------------------------------ K3: env.j2 errors

ENV_ERRORS = [
    "{{ {}[secrets[0][1]|reverse|join] }}",
    "{% extends secrets[0][1]|upper %}",
    "{% include secrets[0][1]|reverse|join %}",
    "{{ secrets[0][1]|map(secrets[0][1]|reverse|join)|list }}",
    "{{ secrets[0][1]|select(secrets[0][1]|reverse|join)|list }}",
    "{{ secrets|selectattr(secrets[0][1]|reverse|join)|list }}",
    "{% for name, value in secrets %}{{ (value|upper ~ '\\x01')|xml }}{% endfor %}",     # a filter's refusal
]


@pytest.mark.parametrize("line", ENV_ERRORS)
def test_an_env_template_error_after_reading_a_secret_is_not_quoted(capsys: pytest.CaptureFixture, lab: Path,
                                                                    line: str) -> None:
    templates(lab, env__j2=BUILTIN_ENV + line + "\n")
    refused(capsys, lab, "env.j2:", "fails after reading secret API_TOKEN", "the error is not shown",
            hidden=(REVERSED, LAB_SECRET.upper()), commands=("render",))


def test_an_env_template_error_before_any_secret_is_still_shown(capsys: pytest.CaptureFixture, lab: Path) -> None:
    templates(lab, env__j2="{{ no_such_name.x }}\n" + BUILTIN_ENV)
    refused(capsys, lab, "env.j2:1", "no_such_name", commands=("render",))


# ------------------------------------------------------------ K5, J3: logrotate.conf

@pytest.mark.parametrize("user", ["{{ api_token | reverse | join }}", "{{ api_token }}"])
def test_an_ssh_user_from_a_vault_var_never_reaches_logrotate(capsys: pytest.CaptureFixture, lab: Path,
                                                              user: str) -> None:
    """Refused at ansible_user (by the inventory, or by the renderer for the logs' home folder)."""
    host_vars(lab, ansible_user=user)
    text = refused(capsys, lab, "host_vars/r1.yml", "ansible_user", "vault var 'api_token'", hidden=(REVERSED,),
                   commands=("render",))
    assert "a secret value would be written to store/" not in text


def test_an_ssh_user_in_a_vault_file_is_refused_at_its_var_for_logrotate(capsys: pytest.CaptureFixture,
                                                                         lab: Path) -> None:
    vault_file(lab, "more_vault.yml", "ansible_user: abc\n")      # too short for the leak scan's text search
    refused(capsys, lab, "group_vars/all/more_vault.yml:1", "ansible_user",
            "a secret value would be written to logrotate.conf", "vault var 'ansible_user'", "rosdeploy_home",
            commands=("render",))


def test_the_renderer_refuses_a_secret_ssh_user_as_the_logs_home() -> None:
    """What the renderer itself does, whatever the inventory refused before (a plain vars mapping:
    the user is secret when it is one of the robot's vault values)."""
    from rosdeploy.errors import RenderError
    from rosdeploy.render import Renderer
    from test_render import make_host, make_spec
    host = make_host(user="vaultuser", vars={"ansible_user": "vaultuser"}, secret_values=frozenset({"vaultuser"}))
    with pytest.raises(RenderError) as caught:
        Renderer(make_spec()).render(host)
    assert [p.key for p in caught.value.problems] == ["ansible_user"]
    assert "logrotate.conf" in caught.value.problems[0].message
    plain = make_host(user="vaultuser", vars={"ansible_user": "vaultuser", "rosdeploy_home": "/home/robot"},
                      secret_values=frozenset({"vaultuser"}))
    logrotate = Renderer(make_spec()).render(plain).file("logrotate.conf").content
    assert "/home/robot/rosdeploy/demo/logs/*/*.log {" in logrotate


@pytest.mark.parametrize("root, glob", [("/opt/robotapps", "/opt/robotapps/lab/logs"),
                                        ("~/apps", "/home/robot/apps/lab/logs")])
def test_log_rotation_follows_the_robots_own_deploy_root(capsys: pytest.CaptureFixture, lab: Path, root: str,
                                                         glob: str) -> None:
    host_vars(lab, rosdeploy_deploy_root=root, ansible_user="robot")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert f"{glob}/*/*.log {{" in (lab / "out" / "r1" / "logrotate.conf").read_text()
    assert "/root/rosdeploy/lab/logs" in (lab / "out" / "r2" / "logrotate.conf").read_text()


# ------------------------------------------------------------ K9, K12b: secrets .env cannot carry

@pytest.mark.parametrize("value, why", [("null", "is null"), ("{a: b}", "holds a mapping, not a string")])
def test_a_secret_env_cannot_carry_is_refused_at_its_vault_var(capsys: pytest.CaptureFixture, lab: Path, value: str,
                                                               why: str) -> None:
    vault_file(lab, "vault.yml", f"api_token: {value}\n")
    text = refused(capsys, lab, "group_vars/all/vault.yml:1", "api_token", "API_TOKEN", why, commands=("render",))
    assert "newline" not in text and "single quote" not in text


@pytest.mark.parametrize("value, why", [(None, "is null"), ("", "is empty"), (["a"], "holds a list, not a string")])
def test_the_renderer_refuses_a_secret_env_cannot_carry(value: object, why: str) -> None:
    from rosdeploy.errors import RenderError
    from rosdeploy.render import Renderer
    from test_render import make_host, make_service, make_spec
    spec = make_spec(make_service(name="s", secret_env={"TOKEN": "tok"}))
    with pytest.raises(RenderError) as caught:
        Renderer(spec).render(make_host(vars={"tok": value}))
    assert [p.key for p in caught.value.problems] == ["tok"]
    assert f"secret TOKEN: the var {why}" in caught.value.problems[0].message


# ------------------------------------------------------------ K11: the leak scan's refusal

@pytest.mark.parametrize("value, file", [('"true"', "fastdds.xml"), ('"1.0.0"', "compose.yml"),
                                         ("lab/driver", "compose.yml")])
def test_a_secret_that_matches_text_the_file_holds_anyway_is_named(capsys: pytest.CaptureFixture, lab: Path,
                                                                  value: str, file: str) -> None:
    vault_file(lab, "vault.yml", f"api_token: {value}\n")
    text = refused(capsys, lab, "group_vars/all/vault.yml:1", f"robot 'r1': a secret value would be written to {file}",
                   "the value of vault var 'api_token' is also text", "coincidence", "longer", commands=("render",))
    assert "store/" not in text, text
    assert text.count(f"robot 'r1': a secret value would be written to {file}") == 1, text


def test_a_leak_names_the_var_that_carried_the_secret(capsys: pytest.CaptureFixture, lab: Path) -> None:
    templates(lab, notes__txt__j2="{{ host.address }}\n")
    host_vars(lab, ansible_host="{{ api_token }}")
    text = refused(capsys, lab, "host_vars/r1.yml", "a secret value would be written to notes.txt",
                   "var 'ansible_host' (computed from vault var 'api_token')", "`secrets:`", commands=("render",))
    assert "coincidence" not in text


# ------------------------------------------------------------ J4: `${` in a .env value

def test_a_secret_holding_a_compose_v1_interpolation_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    """v1 (python-dotenv) read TOKEN='${HOME}x' as /rootx, v2 as ${HOME}x; `$$` is no escape for v1
    (checked with docker-compose 1.29.2 and docker compose 2.40.3 `config`)."""
    vault_file(lab, "vault.yml", 'api_token: "tok-${HOME}x"\n')
    refused(capsys, lab, "group_vars/all/vault.yml:1", "secret API_TOKEN", "`${`", "v1 expands",
            commands=("render",))


@pytest.mark.parametrize("value", ["pa$$w$HOME-x{y}$", "$", "a$b", "{HOME}"])
def test_a_dollar_without_a_brace_is_written_single_quoted(value: str) -> None:
    """Both versions read these literally inside single quotes (v1 expands only `${..}`)."""
    from rosdeploy.render import env_value
    assert env_value(value) == f"'{value}'" or env_value(value) == value


# ------------------------------------------------------------ K6: the address of secret content

def _secret_file(d: dict) -> None:
    d["files"] = {"tok": {"var": "api_token", "target": "/config/tok", "secret": True}}
    d["services"]["driver"]["files"] = ["tok"]


def _rendered(capsys: pytest.CaptureFixture, lab: Path) -> tuple[str, str]:
    """(compose.yml of r1, its store folder names), then the output folder removed."""
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    compose = (lab / "out" / "r1" / "compose.yml").read_text()
    folders = " ".join(sorted(p.name for p in (lab / "out" / "r1" / "store").iterdir()))
    shutil.rmtree(lab / "out")
    return compose, folders


def test_a_secret_files_address_is_keyed_and_stable(capsys: pytest.CaptureFixture, lab: Path) -> None:
    import hashlib
    edit(lab, _secret_file)
    unsalted = hashlib.sha256(LAB_SECRET.encode()).hexdigest()[:16]
    compose, folders = _rendered(capsys, lab)
    assert unsalted not in compose and unsalted not in folders, (compose, folders)
    labels = [line for line in compose.splitlines() if "io.rosdeploy.hash" in line]
    assert len(labels) == 2
    assert (compose, folders) == _rendered(capsys, lab)          # the same secret: the same address, no restart
    vault_file(lab, "vault.yml", "api_token: another-token-value-42\n")
    changed, moved = _rendered(capsys, lab)
    assert moved != folders
    assert [line for line in changed.splitlines() if "io.rosdeploy.hash" in line] != labels


def test_the_hash_label_mixes_no_unsalted_digest_of_a_secret() -> None:
    """The label of a service that reads a secret is not computable from public data and a guess."""
    from rosdeploy import restarts
    from rosdeploy.render import Renderer
    from test_render import make_host, make_service, make_spec
    spec = make_spec(make_service(name="s", secret_env={"TOKEN": "tok"}))
    host = make_host(vars={"tok": "1234"}, secret_values=frozenset({"1234"}))
    label = restarts.release_hashes(Renderer(spec).render(host))["s"]
    assert label == restarts.release_hashes(Renderer(spec).render(host))["s"]
    other = Renderer(spec, secret_key=b"k" * 32).render(host)
    assert restarts.release_hashes(other)["s"] != label      # the key, not the bare secret, decides


# ------------------------------------------------------------ I4, I5: what a template folder holds

def _fifo(path: Path) -> None:
    import os
    os.mkfifo(path)


@pytest.mark.parametrize("name, make, why", [
    ("compose.yml.j2", _fifo, "not a regular file"), ("env.j2", Path.mkdir, "not a regular file"),
    ("compose.yml.j2", lambda p: p.symlink_to("missing.j2"), "a link to a missing file"),
    ("note.txt.j2", _fifo, "not a regular file"), ("note.txt.j2", Path.mkdir, "not a regular file")])
def test_a_template_that_is_no_regular_file_is_refused_at_its_path(capsys: pytest.CaptureFixture, lab: Path,
                                                                   name: str, make: object, why: str) -> None:
    folder = templates(lab)
    make(folder / name)      # type: ignore[operator]
    refused(capsys, lab, f"{folder / name}: {why}", commands=("render",))


def test_a_template_over_the_size_bound_is_refused_before_it_is_compiled(capsys: pytest.CaptureFixture,
                                                                         lab: Path) -> None:
    import time
    folder = templates(lab, big__txt__j2="{{ 1 }}" * 200_000)     # 1.4 MB: about 5 s to compile
    start = time.monotonic()
    refused(capsys, lab, f"{folder / 'big.txt.j2'}: larger than 1 MiB", commands=("render",))
    assert time.monotonic() - start < 3


def test_a_files_template_over_the_size_bound_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    (lab / "params.yaml").write_text("{{ 1 }}" * 200_000)
    edit(lab, lambda d: (d.update(files={"p": {"template": "params.yaml", "target": "/p.yaml"}}),
                         d["services"]["driver"].update(files=["p"])))
    refused(capsys, lab, "params.yaml is over 1 MiB", "`copy:`", commands=("render",))


def test_a_templated_fleet_value_over_the_size_bound_is_refused() -> None:
    from rosdeploy.errors import RenderError
    from rosdeploy.render import Renderer
    from test_render import make_service, make_spec
    with pytest.raises(RenderError) as caught:
        Renderer(make_spec(make_service(environment={"SITE": "{{ 1 }}" * 150_000})))
    assert "a templated value of over 1,048,576 characters" in caught.value.problems[0].message


# ------------------------------------------------------------ I11: a failed include says why

@pytest.mark.parametrize("include, expect", [
    ("_nope.j2", "template '_nope.j2' not found in "),
    ("../../../../etc/passwd", "template '../../../../etc/passwd' is outside the template folder"),
])
def test_an_include_that_finds_nothing_says_why(capsys: pytest.CaptureFixture, lab: Path, include: str,
                                                expect: str) -> None:
    folder = templates(lab, n__txt__j2=f'line one\n{{% include "{include}" %}}\n')
    refused(capsys, lab, f"{folder / 'n.txt.j2'}:2: robot 'r1': {expect}", commands=("render",))


def test_a_partial_that_is_not_utf8_is_blamed_on_itself(capsys: pytest.CaptureFixture, lab: Path) -> None:
    folder = templates(lab, n__txt__j2='{% include "_a.j2" %}\n')
    (folder / "_a.j2").write_bytes(b"ok\ncaf\xe9\n")
    refused(capsys, lab, f"{folder / '_a.j2'}:2: template syntax error: byte 0xe9 is not UTF-8",
            f"included by {folder / 'n.txt.j2'}", commands=("render",))


def test_a_partial_that_is_a_folder_is_named(capsys: pytest.CaptureFixture, lab: Path) -> None:
    folder = templates(lab, n__txt__j2='{% include "_a.j2" %}\n')
    (folder / "_a.j2").mkdir()
    refused(capsys, lab, f"{folder / '_a.j2'}: not a regular file", f"included by {folder / 'n.txt.j2'}:1",
            commands=("render",))


def test_the_release_id_is_no_test_of_a_guess_of_the_env() -> None:
    # the digest hashed .env in the clear: with the other files (readable on the robot) and the
    # release id (a folder name, shown by status), a short secret could be guessed offline
    import hashlib

    from rosdeploy.model import RenderedFile, RenderedRelease

    files = (RenderedFile(".env", "PIN='4711'\n", 0o600), RenderedFile("compose.yml", "services: {}\n"))

    def plain(fs: tuple[RenderedFile, ...]) -> str:
        h = hashlib.sha256()
        for f in fs:
            h.update(f"{f.name}\0{f.mode:o}\0".encode() + f.content.encode() + b"\0")
        return h.hexdigest()

    release = RenderedRelease("r1", "p", "1.0.0", files, (), secret_values=frozenset({"4711"}))
    keyed = RenderedRelease("r1", "p", "1.0.0", files, (), secret_values=frozenset({"4711"}), secret_key=b"k" * 32)
    assert release.digest != plain(files) and keyed.digest not in (plain(files), release.digest)
    again = RenderedRelease("r1", "p", "1.0.0", files, (), secret_values=frozenset({"4711"}), secret_key=b"k" * 32)
    assert again.digest == keyed.digest          # stable: an unchanged release is still "unchanged"


def test_a_project_keys_secret_digests_with_its_vault_password(lab: Path) -> None:
    from rosdeploy import project as project_mod
    from rosdeploy.vault import Vault

    password = (lab / "inventory" / ".vault-password").read_text().strip().encode()
    loaded = project_mod.load_project(str(lab / "fleet.yml"), vault=Vault(password))
    assert loaded.vault_passwords == (password,)
    releases, _ = project_mod.deployable(loaded, loaded.targets())
    other = project_mod.Project(loaded.spec, loaded.inventory, (b"another password",))
    again, _ = project_mod.deployable(other, other.targets())
    assert releases["r1"].release_id != again["r1"].release_id      # the password keys it
    same, _ = project_mod.deployable(loaded, loaded.targets())
    assert same["r1"].release_id == releases["r1"].release_id
