"""Fifth hostile-input audit (issue #18): each case crashed, was let through, or leaked.

1. A `files: {var: ...}` var holding an `!unsafe` string: an internal error (yaml could not
   write the str subclass). Now its text is written, untemplated.
2. The vault password: a password file inside the inventory folder was read as an INI
   inventory and the password printed as a robot name; `--limit @PASSWORD_FILE` printed it too.
   Now that file is refused unread, and every vault password is masked like vault values.
3. `ros_domain_id:` with no value became domain 0 silently; `rosdeploy_ros_domain_id` alone was
   called missing.
4. A NUL byte in an environment value that comes out of an expression or an inventory var went
   into compose.yml (the literal one was refused).
5. `render --out DIR` wrote through a symbolic link DIR/<robot> (into the inventory, say); now
   refused, as a file there already was.
6. A template read the vault values through the context's `secrets` or `host.secret_values`,
   untracked, into a file that is not secret.
7. `!unsafe` in the fleet file was accepted and then templated anyway.
8. A secret named COMPOSE_FILE, COMPOSE_PROFILES or DOCKER_HOST went into .env, where compose
   reads its own settings.
9. `lookup()`, `query()` and `now()` in an inventory var were undefined names, so a fleet value's
   `| default(..)` silently deployed its fallback where Ansible would read the machine.
10. `hostvars['b']` in a's vars failed when b was declared after a.
11. A second `-i` silently replaced the first (Ansible reads both).
12. `ansible_connection: docker` and `ansible_ssh_common_args` were ignored without a word.
13. `rosdeploy_images_max_rate: fast` passed validate and check; plan and apply refused it.
14. A name that is both a host and a group: no warning (Ansible warns).
(A value computed from a vault value quoted one character at a time: test_vault_taint.py.)
(Extra templates named like a release's folders or its built-in files: test_hostile.py.)
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import main
from test_hostile import LAB_SECRET, cli, edit, lab, refused_everywhere, set_env

__all__ = ["lab"]   # the fixture: tests/unit/data/fleet copied, its vault password in place


def password_of(lab: Path) -> str:
    return (lab / "inventory" / ".vault-password").read_text().strip()


def run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out + captured.err


# ------------------------------------------------------------------ 1. !unsafe in a files var

def test_a_files_var_holding_an_unsafe_string_is_written_as_its_text(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(
        'calib:\n  fx: 1.5\n  name: !unsafe "{{ not templated }}"\n')
    (lab / "inventory" / "host_vars" / "r2.yml").write_text("calib: {fx: 2.5}\n")

    def files(d: dict) -> None:
        d["files"] = {"calib": {"var": "calib", "target": "/config/calib.yaml"}}
        d["services"]["driver"]["files"] = ["calib"]
    edit(lab, files)
    for command in ("validate", "check", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 0, (command, text)
    written = yaml.safe_load((lab / "out" / "r1" / "files" / "calib").read_text())
    assert written == {"fx": 1.5, "name": "{{ not templated }}"}


# ------------------------------------------------------------------ 2. the vault password

def test_a_password_file_inside_the_inventory_folder_is_refused_unread(capsys: pytest.CaptureFixture,
                                                                        lab: Path) -> None:
    inside = lab / "inventory" / "vault_pass"    # not hidden: the inventory reads it as INI
    inside.write_text(password_of(lab) + "\n")
    for command in ("validate", "check", "render"):
        code, text = run(capsys, command, str(lab / "fleet.yml"), "--vault-password-file", str(inside),
                         "--out", str(lab / "out")) if command == "render" else \
            run(capsys, command, str(lab / "fleet.yml"), "--vault-password-file", str(inside))
        assert code == 2, (command, text)
        assert f"{inside}: this is the vault password file, not an inventory: move it out of the inventory " \
               "folder" in text, text
        assert password_of(lab) not in text and "Traceback" not in text
        assert not (lab / "out").exists()


@pytest.mark.parametrize("where", ["group_vars/all/vault_pass", "host_vars/r1"])
def test_a_password_file_among_the_vars_files_is_named_for_what_it_is(capsys: pytest.CaptureFixture, lab: Path,
                                                                      where: str) -> None:
    # it was read as a vars file: "a vars file must be a mapping", with no word of what the file is
    inside = lab / "inventory" / where
    inside.parent.mkdir(parents=True, exist_ok=True)
    if inside.parent.name == "host_vars":
        (lab / "inventory" / "host_vars" / "r1.yml").unlink()
    inside.write_text(password_of(lab) + "\n")
    code, text = run(capsys, "validate", str(lab / "fleet.yml"), "--vault-password-file", str(inside))
    assert code == 2, text
    assert f"{inside}: this is the vault password file, not a vars file: move it out of the inventory folder" \
        in text, text
    assert password_of(lab) not in text and "must be a mapping" not in text


def test_a_password_file_given_as_the_inventory_is_refused_unread(capsys: pytest.CaptureFixture, lab: Path) -> None:
    password = lab / "pass"
    password.write_text(password_of(lab) + "\n")
    code, text = run(capsys, "validate", str(lab / "fleet.yml"), "-i", str(password),
                     "--vault-password-file", str(password))
    assert code == 2 and f"{password}: this is the vault password file, not an inventory" in text, text
    assert password_of(lab) not in text


@pytest.mark.parametrize("how", ["limit file", "environment"])
def test_the_vault_password_is_masked_in_messages(capsys: pytest.CaptureFixture, lab: Path,
                                                  monkeypatch: pytest.MonkeyPatch, how: str) -> None:
    secret = password_of(lab)
    if how == "limit file":   # a mistake: the password file given as Ansible's `--limit @FILE`
        argv = ["--vault-password-file", str(lab / "inventory" / ".vault-password"),
                "--limit", f"@{lab / 'inventory' / '.vault-password'}"]
    else:                     # the password in the environment, typed as a pattern
        monkeypatch.setenv("ROSDEPLOY_VAULT_PASSWORD", secret)
        argv = ["--limit", secret]
    code, text = run(capsys, "validate", str(lab / "fleet.yml"), *argv)
    assert code == 2 and "selects no robot" in text and "'********'" in text, text
    assert secret not in text


# ------------------------------------------------------------------ 3. ros_domain_id

@pytest.mark.parametrize("value", ["", "~", "null"])
def test_a_domain_id_with_no_value_is_missing(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("ros_domain_id: 1", f"ros_domain_id: {value}"))
    refused_everywhere(capsys, lab, "hosts.yml:", "'r1' declares no ros_domain_id")


def test_the_prefixed_domain_id_alone_declares_it(capsys: pytest.CaptureFixture, lab: Path) -> None:
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("ros_domain_id: 2", "rosdeploy_ros_domain_id: 7"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "ROS_DOMAIN_ID=7" in (lab / "out" / "r2" / ".env").read_text()


# ------------------------------------------------------------------ 4. NUL in an environment value

@pytest.mark.parametrize("source", ["expression", "inventory var"])
def test_a_nul_that_comes_out_of_a_template_is_refused(capsys: pytest.CaptureFixture, lab: Path,
                                                       source: str) -> None:
    if source == "expression":
        edit(lab, set_env("{{ 'north' ~ '\\x00' ~ 'hall' }}"))
        refused_everywhere(capsys, lab, "fleet.yml:", "services.driver.environment.X: robot 'r1': this value comes "
                                                      "out with a NUL byte")
        return
    # written as an escape in a vars file: refused where it is written, before any template reads it
    (lab / "inventory" / "host_vars" / "r1.yml").write_text('site: "north\\0hall"\n')
    (lab / "inventory" / "host_vars" / "r2.yml").write_text("site: south\n")
    edit(lab, set_env("{{ site }}"))
    refused_everywhere(capsys, lab, "host_vars/r1.yml:1: site: holds a NUL byte (U+0000)")


# ------------------------------------------------------------------ 5. links inside --out

@pytest.mark.parametrize("link", ["r1", "r1/store"])
def test_render_does_not_write_through_a_link_to_a_folder(capsys: pytest.CaptureFixture, lab: Path,
                                                          link: str) -> None:
    out, elsewhere = lab / "out", lab / "inventory" / "host_vars"
    (out / "r1").mkdir(parents=True, exist_ok=True)
    if link == "r1":
        (out / "r1").rmdir()
    (out / link).symlink_to(elsewhere)
    before = sorted(os.listdir(elsewhere))
    code, text = cli(capsys, lab, "render")
    assert code == 2, text
    assert f"{out / link}: --out: cannot write there (a symbolic link, which render does not write through)" in text
    assert sorted(os.listdir(elsewhere)) == before
    assert not any(p.name.startswith(".rosdeploy-render-") for p in out.iterdir())


def test_render_replaces_a_link_where_a_file_goes(capsys: pytest.CaptureFixture, lab: Path) -> None:
    out, elsewhere = lab / "out", lab / "elsewhere"
    (out / "r2").mkdir(parents=True)
    elsewhere.mkdir()
    (elsewhere / "compose.yml").write_text("theirs\n")
    (out / "r2" / "compose.yml").symlink_to(elsewhere / "compose.yml")
    (out / "r2" / "notes.txt").write_text("kept\n")
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert (elsewhere / "compose.yml").read_text() == "theirs\n"
    assert not (out / "r2" / "compose.yml").is_symlink() and "services:" in (out / "r2" / "compose.yml").read_text()
    assert (out / "r2" / "notes.txt").read_text() == "kept\n"


# ------------------------------------------------------------------ 6. vault values through the context

@pytest.mark.parametrize("template, expect", [
    ("{% for name, value in secrets %}{{ value | reverse }}{% endfor %}\n",
     "`secrets` holds the vault values that go to .env, and only env.j2 may read them"),
    ("{{ secrets[0][1] | list | join(' ') }}\n", "only env.j2 may read them"),
    ("{{ host.secret_values | list | first | replace('-', '_') }}\n", "secret_values"),
    ("{{ host | attr('secret_values') | list }}\n", "secret_values"),
    ("{{ host['secret_values'] | list }}\n", "secret_values"),
])
def test_a_template_cannot_read_vault_values_untracked(capsys: pytest.CaptureFixture, lab: Path,
                                                       template: str, expect: str) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "leak.txt.j2").write_text(template)
    edit(lab, lambda d: d.update(templates="./templates"))
    refused_everywhere(capsys, lab, "templates/leak.txt.j2:1: robot 'r1': ", expect)


def test_a_template_may_count_the_secrets_and_env_j2_still_writes_them(capsys: pytest.CaptureFixture,
                                                                         lab: Path) -> None:
    (lab / "templates").mkdir()
    (lab / "templates" / "count.txt.j2").write_text("{{ secrets | length }} secret(s)\n")
    edit(lab, lambda d: d.update(templates="./templates"))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert (lab / "out" / "r1" / "count.txt").read_text() == "1 secret(s)\n"
    assert f"API_TOKEN={LAB_SECRET}" in (lab / "out" / "r1" / ".env").read_text()


def test_a_fleet_value_cannot_read_host_secret_values(capsys: pytest.CaptureFixture, lab: Path) -> None:
    edit(lab, set_env("{{ host.secret_values | list | first | reverse }}"))
    refused_everywhere(capsys, lab, "fleet.yml:", "services.driver.environment.X: robot 'r1': ", "secret_values")


# ------------------------------------------------------------------ 7. !unsafe in the fleet file

def test_an_unsafe_fleet_value_is_not_templated(capsys: pytest.CaptureFixture, lab: Path) -> None:
    fleet = lab / "fleet.yml"
    fleet.write_text(fleet.read_text().replace("    image: lab/driver\n", '    image: lab/driver\n'
                                               '    environment: {RAW: !unsafe "{{ 1 + 1 }}", SUM: "{{ 1 + 1 }}"}\n'))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    env = yaml.safe_load((lab / "out" / "r1" / "compose.yml").read_text())["services"]["driver"]["environment"]
    assert env["RAW"] == "{{ 1 + 1 }}" and env["SUM"] == "2"


# ------------------------------------------------------------------ 8. compose's own settings in .env

@pytest.mark.parametrize("name", ["COMPOSE_FILE", "COMPOSE_PROFILES", "DOCKER_HOST"])
def test_a_secret_may_not_set_a_setting_of_compose_itself(capsys: pytest.CaptureFixture, lab: Path,
                                                          name: str) -> None:
    # .env is where compose reads them from: the file, the profiles or the engine would change unseen
    edit(lab, lambda d: d["services"]["bridge"].update(secrets={name: "api_token"}))
    refused_everywhere(capsys, lab, "fleet.yml:", f"services.bridge.secrets.{name}: {name} in .env is a setting "
                                                    "of docker compose itself")


# ------------------------------------------------------------------ 9. Ansible's machine-reading globals

def inventory_var(lab: Path, text: str) -> None:
    (lab / "inventory" / "host_vars" / "r1.yml").write_text(text)


@pytest.mark.parametrize("expr", ["lookup('env', 'HOME')", "query('file', '/etc/hostname') | first", "now().year"])
def test_a_lookup_in_an_inventory_var_is_an_error_even_under_a_default(capsys: pytest.CaptureFixture, lab: Path,
                                                                        expr: str) -> None:
    inventory_var(lab, f'site: "{{{{ {expr} }}}}"\n')
    edit(lab, set_env("{{ site | default('fallback') }}"))
    name = expr.split("(")[0]
    refused_everywhere(capsys, lab, "host_vars/r1.yml:1: site: robot 'r1'",
                       f"{name}() reads this machine", "rosdeploy never does for an inventory")


def test_an_ansible_filter_rosdeploy_lacks_says_which_it_has(capsys: pytest.CaptureFixture, lab: Path) -> None:
    inventory_var(lab, 'site: "{{ \'north\' | b64encode }}"\n')
    edit(lab, set_env("{{ site }}"))
    refused_everywhere(capsys, lab, "No filter named 'b64encode'", "Jinja2's filters and basename, dirname")


# ------------------------------------------------------------------ 10. hostvars of a later host

def test_hostvars_of_a_host_declared_later_are_read(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # a var the inventory itself reads (ros_domain_id, ansible_host…) is read while robots are built:
    # r2 is declared after r1, and `hostvars['r2']` was "no attribute 'r2'"
    hosts = lab / "inventory" / "hosts.yml"
    hosts.write_text(hosts.read_text().replace("ros_domain_id: 1", "ros_domain_id: \"{{ hostvars['r2'].ros_domain_id "
                                                                   "+ 5 }}\""))
    code, text = cli(capsys, lab, "render")
    assert code == 0, text
    assert "ROS_DOMAIN_ID=7" in (lab / "out" / "r1" / ".env").read_text()


# ------------------------------------------------------------------ 11. -i twice

def test_a_second_inventory_option_is_refused(capsys: pytest.CaptureFixture, lab: Path) -> None:
    inventory = str(lab / "inventory")
    code, text = cli(capsys, lab, "validate", "-i", inventory, "-i", inventory)
    assert code == 2 and "argument -i/--inventory: given twice" in text, text
    code, text = cli(capsys, lab, "validate", "-i", "r1,r2,")
    assert code == 2 and "Ansible's host list, `-i host1,host2,`, is not read" in text, text


# ------------------------------------------------------------------ 12. connection vars rosdeploy does not take

@pytest.mark.parametrize("var, value, words", [
    ("ansible_connection", "docker", "'docker' is ignored: rosdeploy reaches every robot over SSH"),
    ("ansible_ssh_common_args", "-o ProxyCommand=nc bastion 22", "ignored: rosdeploy runs no ssh command"),
    ("ansible_ssh_extra_args", "-o StrictHostKeyChecking=no", "always checks host keys"),
])
def test_a_connection_var_rosdeploy_ignores_is_named(capsys: pytest.CaptureFixture, lab: Path, var: str,
                                                     value: str, words: str) -> None:
    inventory_var(lab, yaml.safe_dump({var: value}))
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and f"warning: {lab / 'inventory' / 'host_vars' / 'r1.yml'}:1: {var}: " in text, text
    assert words in text


@pytest.mark.parametrize("value", ["ssh", "smart", "paramiko"])
def test_an_ssh_connection_var_gets_no_warning(capsys: pytest.CaptureFixture, lab: Path, value: str) -> None:
    inventory_var(lab, f"ansible_connection: {value}\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "ansible_connection" not in text, text


# ------------------------------------------------------------------ 13. a robot's own rate

@pytest.mark.parametrize("value, words", [("fast", "got 'fast'"), ("2Mbps", "bits per second; write bytes")])
def test_a_robots_rate_is_checked_at_load(capsys: pytest.CaptureFixture, lab: Path, value: str, words: str) -> None:
    inventory_var(lab, f"rosdeploy_images_max_rate: {value}\n")
    refused_everywhere(capsys, lab, "host_vars/r1.yml:1: rosdeploy_images_max_rate: robot 'r1': must be a rate in "
                                    "bytes per second from 1kB/s up", words)


# ------------------------------------------------------------------ 14. a host named like a group

def test_a_host_named_like_a_group_is_warned_about(capsys: pytest.CaptureFixture, lab: Path) -> None:
    hosts = lab / "inventory" / "hosts.yml"
    data = yaml.safe_load(hosts.read_text())
    data["all"]["children"]["r1"] = {"hosts": {"r2": None}}     # a group `r1` holding r2
    hosts.write_text(yaml.safe_dump(data))
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "'r1' is both a host and a group: `--limit r1` selects the host only" in text, text
