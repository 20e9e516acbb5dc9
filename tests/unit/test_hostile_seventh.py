"""Seventh hostile-input audit (fuzzer findings): a become var computed from a vault var was
quoted by the host-changes warning, and a broken template in `logrotate_keep` or `dds_peers`
was reported as a wrong value ("got Undefined") instead of as the template error it is."""
from __future__ import annotations

from pathlib import Path

import pytest

import test_hostile
from test_hostile import LAB_SECRET, cli
from test_vault_taint import group_vars

lab = test_hostile.lab


@pytest.mark.parametrize("var, value, where", [
    ("ansible_become_user", "{{ api_token[1:] }}", "ansible_become_user is '********'"),
    ("ansible_become_method", "{{ api_token|upper }}", "ansible_become_method '********'"),
])
def test_a_become_var_computed_from_a_vault_var_is_never_quoted(capsys: pytest.CaptureFixture, lab: Path,
                                                                var: str, value: str, where: str) -> None:
    group_vars(lab, **{var: value})
    for command in ("validate", "check"):
        code, text = cli(capsys, lab, command)
        assert code == 0 and where in text, text                 # a warning, at its var
        for leaked in (LAB_SECRET[1:], LAB_SECRET.upper()):
            assert leaked not in text, (command, text)


def test_an_ssh_user_computed_from_a_vault_var_is_refused_unquoted(capsys: pytest.CaptureFixture, lab: Path) -> None:
    # it was a warning at the become check; it is refused at load since the eighth round: plan and
    # status show where and how they connect, and only a vault value's own text is masked there
    group_vars(lab, ansible_user="{{ api_token[1:] }}", ansible_become=False)
    for command in ("validate", "check"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and "ansible_user is computed from vault var 'api_token'" in text, (command, text)
        for leaked in (LAB_SECRET[1:], LAB_SECRET.upper()):
            assert leaked not in text, (command, text)


def test_a_plain_become_user_is_still_named(capsys: pytest.CaptureFixture, lab: Path) -> None:
    group_vars(lab, ansible_become_user="deploy")
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and "ansible_become_user is 'deploy': host changes need root" in text


@pytest.mark.parametrize("var", ["logrotate_keep", "dds_peers", "logrotate_size"])
@pytest.mark.parametrize("value, why", [("{{ 1|bogus }}", "No filter named 'bogus'"),
                                        ("{{ zq_nothing }}", "'zq_nothing' is undefined")])
def test_a_broken_template_in_a_var_the_renderer_reads_is_reported_as_one(capsys: pytest.CaptureFixture, lab: Path,
                                                                          var: str, value: str, why: str) -> None:
    group_vars(lab, **{var: value})
    for command in ("validate", "render"):
        code, text = cli(capsys, lab, command)
        assert code == 2 and f"{var}: robot" in text and "cannot template" in text and why in text, text
        assert "Undefined" not in text
        assert not (lab / "out").exists()
