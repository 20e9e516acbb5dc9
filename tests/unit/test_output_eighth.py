"""Eighth round (probe K items 1, 2, 8, 10, 12d; probe J item 15): what Output writes.

--json is masked as data, so a secret json.dumps escapes is still masked and a secret equal to a
word of the document cannot break it; characters that reverse, hide or split a line are escaped;
a refused `render --out a/b/c` leaves no folder it made; a failing command's document has `error`.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
import yaml

from rosdeploy.cli import _finish, main
from rosdeploy.errors import Problem
from rosdeploy.output import Output
from test_hostile import cli, edit, lab  # noqa: F401  (lab: the fixture)
from test_vault_taint import vault_file

UNICODE_SECRET = "Sécrét-ünïcode-tøken-42"
ESCAPED_SECRET = 'back\\slash"quote-token'
TEMPLATES = Path(__file__).resolve().parents[2] / "rosdeploy" / "templates"


def _document(secrets: list[str], data: dict, code: int = 0) -> tuple[str, str]:
    stdout, stderr = io.StringIO(), io.StringIO()
    out = Output(stdout=stdout, stderr=stderr, as_json=True, color="never", hold=True)
    out.mask(secrets)
    out.document(data)
    out.finish(code)
    return stdout.getvalue(), stderr.getvalue()


# ------------------------------------------------------------- K1: escaped secrets

@pytest.mark.parametrize("secret", [UNICODE_SECRET, ESCAPED_SECRET])
def test_a_secret_json_escapes_is_masked_in_the_document(secret: str) -> None:
    text, _ = _document([secret], {"message": f"restart policy `{secret}` is unknown", "items": [secret]})
    doc = json.loads(text)
    assert doc["message"] == "restart policy `********` is unknown" and doc["items"] == ["********"]
    assert secret not in text and json.dumps(secret)[1:-1] not in text, text


def test_validate_json_masks_a_unicode_secret_the_rendered_compose_shows(capsys: pytest.CaptureFixture,
                                                                        lab: Path) -> None:  # noqa: F811
    vault_file(lab, "vault.yml", f'api_token: "{UNICODE_SECRET}"\n')
    (lab / "templates").mkdir()
    compose = (TEMPLATES / "compose.yml.j2").read_text()
    line = "    restart: {{ svc.restart | compose_str }}\n"
    assert line in compose
    (lab / "templates" / "compose.yml.j2").write_text(compose.replace(
        line, "    restart: {{ '\"${API_TOKEN}\"' if svc.name == 'bridge' else svc.restart | compose_str }}\n"))
    edit(lab, lambda d: d.update(templates="./templates"))
    password = str(lab / "inventory" / ".vault-password")
    code = main(["--json", "validate", str(lab / "fleet.yml"), "--vault-password-file", password])
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert code == 2 and doc["exit_code"] == 2 and "********" in captured.out, captured.out
    assert "S\\u00e9cr\\u00e9t" not in captured.out and UNICODE_SECRET not in captured.out + captured.err


# ------------------------------------------------------------ K2: JSON words as secrets

def test_a_secret_equal_to_a_json_word_or_key_leaves_the_document_whole() -> None:
    secrets = ["null", "true", "1252", "exit_code", "severity", "message"]
    text, _ = _document(secrets, {"ok": True, "fix": None, "line": 1252,
                                  "problems": [{"severity": "warning", "message": "true to null, at 1252"}]}, 2)
    doc = json.loads(text)
    assert doc["exit_code"] == 2 and doc["ok"] is False and doc["fix"] is None and doc["line"] == 1252
    assert doc["problems"] == [{"severity": "warning", "message": "******** to ********, at ********"}]


def test_render_json_refusal_is_one_document_with_an_unused_vault_value_null(capsys: pytest.CaptureFixture,
                                                                           lab: Path) -> None:  # noqa: F811
    vault_file(lab, "vault.yml", 'api_token: unit-test-token-7d1e\nunused_thing: "null"\n')
    password = str(lab / "inventory" / ".vault-password")
    code = main(["--json", "render", str(lab / "fleet.yml"), "--vault-password-file", password,
                 "--out", str(lab / "inventory")])
    doc = json.loads(capsys.readouterr().out)
    assert code == 2 and doc["exit_code"] == 2 and doc["ok"] is False
    assert doc["error"]["problems"][0]["line"] is None and doc["error"]["problems"][0]["fix"] is None


def test_a_vault_password_error_keeps_the_error_prefix(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    (lab / "inventory" / ".vault-password").write_text("error\n")
    vault_file(lab, "vault.yml", "api_token: unit-test-token-7d1e\n")
    edit(lab, lambda d: d["services"]["driver"].update(privileged=True))
    code, text = cli(capsys, lab, "validate")
    lines = text.splitlines()
    assert code == 2 and lines[0].startswith("error: ") and "privileged" in lines[0], text
    assert "********:" not in text, text


def test_a_severity_head_is_kept_but_the_rest_of_the_line_is_masked() -> None:
    stdout, stderr = io.StringIO(), io.StringIO()
    out = Output(stdout=stdout, stderr=stderr, color="always")
    out.mask(["warning", "error", "device-unstable"])
    out.line(out.paint("warning[device-unstable] maps /dev/x: error", "yellow"))
    out.warn("warning: an error here")
    assert "warning[device-unstable] maps /dev/x: ********" in stdout.getvalue()
    assert stderr.getvalue().startswith("\033[33mwarning: an ******** here")
    out.mask(["error: a-long-secret"])    # a secret running past the head: masked whole
    out.error("error: a-long-secret shown")
    assert "\033[31m******** shown" in stderr.getvalue(), stderr.getvalue()


# ------------------------------------------------------- K10, J15: unseen characters

UNSEEN = ["\u202e", "\u202a", "\u2066", "\u2069", "\u200e", "\u200f", "\u061c", "\u200b", "\u200d", "\u2060",
          "\ufeff", "\u2028", "\u2029", "\x85"]


@pytest.mark.parametrize("char", UNSEEN)
def test_a_character_that_reverses_hides_or_splits_a_line_is_escaped(char: str) -> None:
    escaped = f"\\x{ord(char):02x}" if ord(char) < 0x100 else f"\\u{ord(char):04x}"
    stdout, stderr = io.StringIO(), io.StringIO()
    out = Output(stdout=stdout, stderr=stderr, color="never")
    out.line(f"file x{char}evil.yml")
    out.error(str(Problem(f"x{char}evil.yml", 2, f"k{char}", "invalid YAML")))
    out.table(["ROBOT"], [[f"r{char}1"]])
    written = stdout.getvalue() + stderr.getvalue()
    assert char not in written and written.count(escaped) == 4, written
    assert f"x{escaped}evil.yml:2: k{escaped}: invalid YAML" in written


def test_a_file_name_with_a_right_to_left_override_is_shown_escaped(capsys: pytest.CaptureFixture,
                                                                    lab: Path) -> None:  # noqa: F811
    (lab / "inventory" / "group_vars" / "all" / "x\u202eevil.yml").write_text("a: [\n")
    code, text = cli(capsys, lab, "validate")
    assert code == 2 and "x\\u202eevil.yml" in text and "\u202e" not in text, text


# -------------------------------------------------------- K8: parents of a refused --out

def test_a_refused_render_leaves_no_parent_folder_it_made(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    edit(lab, lambda d: d["services"]["driver"].update(privileged=True))
    (lab / "kept").mkdir()
    for out in (lab / "outs" / "a" / "b" / "c", lab / "kept" / "a" / "b"):   # refused after rendering
        code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                     str(lab / "inventory" / ".vault-password"), "--out", str(out)])
        assert code == 2, capsys.readouterr()
    assert not (lab / "outs").exists()
    assert (lab / "kept").is_dir() and not any((lab / "kept").iterdir())


def test_a_render_that_lands_keeps_the_parents_it_made(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    out = lab / "outs" / "a" / "b"
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(out)])
    assert code == 0, capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["r1", "r2"]


# ---------------------------------------------------- K12d: one shape of a failing document

@pytest.mark.parametrize("command, listed", [("validate", "problems"), ("check", "findings")])
def test_a_failing_rule_gives_the_document_its_error(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                     command: str, listed: str) -> None:
    edit(lab, lambda d: d["services"]["driver"].update(privileged=True))
    code = main(["--json", command, str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password")])
    doc = json.loads(capsys.readouterr().out)
    assert code == 2 and doc["ok"] is False and doc["exit_code"] == 2
    assert doc["error"]["kind"] == "input" and [p["rule"] for p in doc["error"]["problems"]] == ["privileged"]
    assert "services.driver.privileged" in doc["error"]["message"]
    assert {p["rule"] for p in doc[listed]} >= {"privileged", "gpu-unavailable"}    # the warnings stay


def test_a_load_failure_and_a_passing_validate_keep_their_shapes(capsys: pytest.CaptureFixture,
                                                                 lab: Path) -> None:  # noqa: F811
    password = str(lab / "inventory" / ".vault-password")
    assert main(["--json", "validate", str(lab / "fleet.yml"), "--vault-password-file", password]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is True and "error" not in doc
    data = yaml.safe_load((lab / "fleet.yml").read_text())
    (lab / "fleet.yml").write_text(yaml.safe_dump({**data, "servces": {}}))
    assert main(["--json", "validate", str(lab / "fleet.yml"), "--vault-password-file", password]) == 2
    doc = json.loads(capsys.readouterr().out)
    assert doc["error"]["kind"] == "input" and doc["error"]["problems"]


def test_a_command_failing_by_its_exit_code_gets_an_error_member() -> None:
    stdout = io.StringIO()
    out = Output(stdout=stdout, stderr=io.StringIO(), as_json=True, hold=True)
    out.document({"robots": [{"host": "r1", "reachable": False, "error": "unreachable"}]})
    assert _finish(out, 3) == 3
    doc = json.loads(stdout.getvalue())
    assert doc["ok"] is False and doc["exit_code"] == 3 and doc["robots"][0]["error"] == "unreachable"
    assert doc["error"]["kind"] == "error" and doc["error"]["problems"] == [] and doc["error"]["message"]


def test_the_run_record_masks_values_not_its_json_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # result.json on disk had the --json document's defect: a secret JSON escapes was written whole
    from rosdeploy import runlog
    from rosdeploy.results import FleetResult, HostResult

    monkeypatch.setenv("ROSDEPLOY_RUNS_DIR", str(tmp_path))
    secret = "Sécrét-ünïcode-tøken-42"
    out = Output(io.StringIO(), io.StringIO(), color=False)
    out.mask([secret, "null"])
    result = FleetResult("apply", (HostResult("r1", "failed", reason=f"bad {secret}"),), run_id="run-1")
    text = (runlog.save(result, out.masked) / "result.json").read_text()
    record = json.loads(text)
    assert secret not in json.dumps(record, ensure_ascii=False) and "********" in text
    assert record["hosts"][0]["old_release"] is None
