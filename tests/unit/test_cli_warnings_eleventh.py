"""Round 11 (probe T), defects 6 and 8c.

6. The inventory's warnings (an odd group name, another tool's var ignored, a duplicate key, a
   --limit term that matches nothing) went to stderr only: `validate --json` and `check --json`
   left them out of `problems`/`findings`, `render --json` had no place for them, and the text
   summary's "N warning(s)" did not count them.
8c. A dynamic inventory script that printed more than the bound on stderr was told it "printed
   more than 64 MB", as if its JSON were too long.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from rosdeploy.errors import InventoryError
from rosdeploy.inventory import load_inventory
from test_hostile import cli, lab  # noqa: F401  (the fixture)

ODD_GROUP = """\
all:
  children:
    lab:
      hosts:
        r1: {ansible_host: 127.0.0.1, ros_domain_id: 1}
        r2: {ansible_host: 127.0.0.2, ros_domain_id: 2}
    "a:b": {hosts: {r1: }}
"""
ODD = "group name 'a:b'"
GPU = "gpu-unavailable"     # the lab fleet's own warning (r2 has no GPU)


@pytest.fixture
def odd(lab: Path) -> Path:  # noqa: F811
    (lab / "inventory" / "hosts.yml").write_text(ODD_GROUP)
    return lab


def document(capsys: pytest.CaptureFixture, folder: Path, command: str, *argv: str) -> tuple[int, dict, str]:
    code, text = cli(capsys, folder, command, "--json", *argv)
    start = text.index("{\n")        # the document on stdout; stderr (the text warnings) follows it
    doc, end = json.JSONDecoder().raw_decode(text, start)
    return code, doc, text[end:]


def by_rule(items: list[dict], rule: str) -> list[dict]:
    return [item for item in items if item["rule"] == rule]


# ------------------------------------------------------------------ 6. --json and the count

def test_validate_json_lists_an_inventory_warning_among_its_problems(capsys: pytest.CaptureFixture,
                                                                      odd: Path) -> None:
    code, doc, err = document(capsys, odd, "validate")
    assert code == 0 and doc["ok"] is True, doc
    [found] = by_rule(doc["problems"], "inventory")
    assert found["severity"] == "warning" and ODD in found["message"], found
    assert (Path(found["file"]).name, found["line"], found["key"]) == ("hosts.yml", 7, "all.children.a:b"), found
    assert found["fix"] is None
    assert by_rule(doc["problems"], GPU), doc      # the fleet's own warning is still there, in the same list
    assert ODD in err                               # and still said on stderr


def test_check_json_lists_inventory_and_limit_warnings_among_its_findings(capsys: pytest.CaptureFixture,
                                                                          odd: Path) -> None:
    code, doc, _ = document(capsys, odd, "check", "-l", "lab:nomatch")
    assert code == 0 and doc["ok"] is True, doc
    [inventory] = by_rule(doc["findings"], "inventory")
    assert inventory["severity"] == "warning" and ODD in inventory["message"]
    [limit] = by_rule(doc["findings"], "limit")
    assert limit["severity"] == "warning" and "'nomatch' matches no host or group" in limit["message"], limit
    assert limit["file"] == "--limit"
    assert by_rule(doc["findings"], GPU)
    assert [f["severity"] for f in doc["findings"]] == sorted((f["severity"] for f in doc["findings"]),
                                                              key=["error", "warning", "info"].index)


def test_render_json_has_the_warnings_of_the_inventory_and_of_the_fleet(capsys: pytest.CaptureFixture,
                                                                        odd: Path) -> None:
    code, doc, _ = document(capsys, odd, "render")
    assert code == 0 and len(doc["robots"]) == 2, doc
    assert [w["rule"] for w in doc["warnings"]] == ["inventory", GPU], doc["warnings"]
    assert all(w["severity"] == "warning" for w in doc["warnings"])


def test_a_render_that_fails_keeps_the_inventory_warnings_in_its_document(capsys: pytest.CaptureFixture,
                                                                          odd: Path) -> None:
    (odd / "templates").mkdir()
    (odd / "templates" / "logrotate.conf.j2").write_text("{{ no_such_variable }}\n")
    fleet = odd / "fleet.yml"
    fleet.write_text(fleet.read_text() + "templates: ./templates\n")
    code, doc, _ = document(capsys, odd, "render")
    assert code == 2 and doc["error"]["kind"] == "input", doc
    assert [w["rule"] for w in doc["warnings"]] == ["inventory"], doc


def test_apply_json_stopped_before_any_robot_has_the_inventory_warnings(capsys: pytest.CaptureFixture,
                                                                        odd: Path) -> None:
    """apply, plan, status...: one `warnings` list, in the document of a failure too (a
    template error stops apply here, before any robot is asked)."""
    (odd / "templates").mkdir()
    (odd / "templates" / "logrotate.conf.j2").write_text("{{ no_such_variable }}\n")
    fleet = odd / "fleet.yml"
    fleet.write_text(fleet.read_text() + "templates: ./templates\n")
    code, doc, _ = document(capsys, odd, "apply", "--yes")
    assert code == 2 and doc["error"]["kind"] == "input", doc
    [found] = doc["warnings"]
    assert (found["rule"], found["severity"]) == ("inventory", "warning") and ODD in found["message"], found


def test_the_text_summaries_count_the_inventory_warnings(capsys: pytest.CaptureFixture, odd: Path) -> None:
    code, text = cli(capsys, odd, "validate")
    assert code == 0 and "2 robot(s), 2 warning(s)\n" in text, text
    assert text.index(ODD) < text.index(GPU.split("-")[0]), text     # the order is unchanged: inventory first
    code, text = cli(capsys, odd, "check", "-l", "lab:nomatch")
    assert code == 0 and "OK " in text and "2 robot(s), 3 warning(s)" in text, text


def test_a_warning_made_with_the_default_severity_is_a_warning_in_json(capsys: pytest.CaptureFixture,
                                                                       lab: Path) -> None:  # noqa: F811
    """A group named as a host, a duplicate key and another tool's var: each a warning, with its place."""
    (lab / "inventory" / "hosts.yml").write_text(ODD_GROUP.replace('"a:b"', "r2").replace(
        "ros_domain_id: 1}", "ros_domain_id: 1, ros_domain_id: 1}"))
    (lab / "inventory" / "host_vars" / "r1.yml").write_text('gpu: true\nready: "true"\n')
    code, doc, _ = document(capsys, lab, "validate")
    assert code == 0, doc
    found = by_rule(doc["problems"], "inventory")
    texts = " | ".join(f["message"] for f in found)
    assert "both a host and a group" in texts and "another tool's variable" in texts, texts
    assert any("ros_domain_id" in f["message"] or f["key"].endswith("ros_domain_id") for f in found), found
    assert {f["severity"] for f in found} == {"warning"}, found
    code, text = cli(capsys, lab, "validate")
    assert code == 0 and f"{len(found) + 1} warning(s)" in text, text


# ------------------------------------------------------------------ 8c. which stream was too long

def _chatty(tmp_path: Path, body: str) -> Path:
    script = tmp_path / "dyn.sh"
    script.write_text(f"#!/bin/sh\n{body}\necho '{{\"lab\": [\"r1\"]}}'\n")
    script.chmod(0o755)
    return script


def test_a_script_too_chatty_on_stderr_is_told_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy.inventory import script as script_module
    monkeypatch.setattr(script_module, "MAX_OUTPUT", 1 << 20)
    script = _chatty(tmp_path, "head -c 3000000 /dev/zero | tr '\\0' x >&2")
    with pytest.raises(InventoryError, match=r"dyn.sh --list` printed more than 1 MB on stderr") as caught:
        load_inventory(str(script))
    assert "on stdout" not in str(caught.value)


def test_a_script_too_long_on_stdout_is_told_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rosdeploy.inventory import script as script_module
    monkeypatch.setattr(script_module, "MAX_OUTPUT", 1 << 20)
    script = _chatty(tmp_path, "head -c 3000000 /dev/zero | tr '\\0' x")
    with pytest.raises(InventoryError, match=r"dyn.sh --list` printed more than 1 MB on stdout: a dynamic "
                                             "inventory prints a JSON object of groups"):
        load_inventory(str(script))


def test_plan_json_has_the_warnings_of_the_inventory_and_of_the_fleet(capsys: pytest.CaptureFixture,
                                                                      odd: Path) -> None:
    """The lab's robots answer no SSH: plan still prints its document, `warnings` in it."""
    code, doc, _ = document(capsys, odd, "plan")
    assert code == 3 and len(doc["robots"]) == 2, doc
    assert [w["rule"] for w in doc["warnings"]] == ["inventory", GPU], doc["warnings"]
