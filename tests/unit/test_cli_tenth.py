"""Tenth round, command line (probe P): --limit bounded in time and output, an @file's control
characters, a regex Python warns about, thread exhaustion, a newline in --out, and a short vault
password that is one of rosdeploy's own words."""
from __future__ import annotations

import io
import json
import threading
import warnings
from pathlib import Path

import pytest

from rosdeploy import patterns, suggest
from rosdeploy.cli import main
from rosdeploy.errors import InputError
from rosdeploy.output import MASK, Output
from test_hostile import cli, lab  # noqa: F401  (the fixture)

HOSTS = tuple(f"r{i}" for i in range(100))
GROUPS = {"all": HOSTS, "robots": HOSTS}


# --- item 1: many unmatched terms ------------------------------------------------------------

def test_many_unmatched_names_warn_five_and_count_the_rest(monkeypatch: pytest.MonkeyPatch) -> None:
    """A did-you-mean for every one of 2,000 terms (minutes at 20,000) and a warning line each:
    now five named, the rest counted in one warning."""
    calls = []
    real = suggest.did_you_mean
    monkeypatch.setattr(suggest, "did_you_mean", lambda word, choices: calls.append(word) or real(word, choices))
    found: list = []
    chosen = patterns.select(",".join(["r1", *(f"x{i}" for i in range(2000))]), HOSTS, GROUPS, warnings=found)
    assert chosen == ("r1",)
    assert len(calls) <= patterns.MAX_SHOWN_TERMS, len(calls)
    assert len(found) == patterns.MAX_SHOWN_TERMS + 1, len(found)
    assert "and 1,995 more term(s) that match no host or group" in found[-1].message
    assert all(p.severity == "warning" for p in found)


def test_many_unmatched_exclusions_are_five_errors_and_a_count(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    real = suggest.did_you_mean
    monkeypatch.setattr(suggest, "did_you_mean", lambda word, choices: calls.append(word) or real(word, choices))
    with pytest.raises(InputError) as caught:
        patterns.select("r1:" + ":".join(f"!x{i}" for i in range(300)), HOSTS, GROUPS)
    assert len(caught.value.problems) == patterns.MAX_SHOWN_TERMS + 1
    assert "and 295 more exclusion(s)" in caught.value.problems[-1].message
    assert len(calls) <= patterns.MAX_SHOWN_TERMS


def test_a_repeated_unmatched_term_is_one_warning() -> None:
    found: list = []
    patterns.select("r1," + ",".join(["nope"] * 50), HOSTS, GROUPS, warnings=found)
    assert len(found) == 1 and "'nope'" in found[0].message


def test_too_many_globs_for_the_inventory_are_refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """2,000 globs over 10,000 hosts took 30 s; 20,000 in an @file, minutes. Scaled down here."""
    monkeypatch.setattr(patterns, "MAX_MATCH_WORK", 1000, raising=False)
    (tmp_path / "globs").write_text("\n".join(f"r*{i}x" for i in range(30)))
    for pattern in (f"@{tmp_path / 'globs'}", "r1:" + ":".join(f"!r*{i}x" for i in range(30))):
        with pytest.raises(InputError) as caught:
            patterns.select(pattern, HOSTS, GROUPS)
        text = str(caught.value)
        assert "30 globs or regular expressions" in text and "1,000 tests" in text, text
    # host names cost no test: any number of them is fine, and globs within the bound still work
    assert patterns.select(",".join(HOSTS) + ",r*9", HOSTS, GROUPS) == HOSTS


def test_names_globs_and_subscripts_select_as_before() -> None:
    groups = {"all": HOSTS, "robots": HOSTS, "site.a": ("r1", "r2"), "r5": ("r6", "r7")}
    assert patterns.select("robots[1:2]", HOSTS, groups) == ("r1", "r2")
    assert patterns.select("r5", HOSTS, groups) == ("r5",)        # a host name is never read as a pattern
    assert patterns.select("r5[1]", HOSTS, groups) == ("r7",)
    assert patterns.select("site.a:&r2", HOSTS, groups) == ("r2",)
    assert patterns.select("r?:!r[1-8]", HOSTS, groups) == ("r0", "r9")
    assert patterns.select("r9*:&~r9[0-2]", HOSTS, groups) == ("r90", "r91", "r92")


# --- item 3: a regex Python warns about ------------------------------------------------------

@pytest.mark.parametrize("regex", ["~r[9&&q]", "~r[9||q]", "~[[:digit:]q]"])
def test_a_regex_python_warns_about_is_a_warning_of_ours(regex: str) -> None:
    found: list = []
    with warnings.catch_warnings(record=True) as python:
        warnings.simplefilter("always")
        patterns.select(f"r1,{regex}", HOSTS, GROUPS, warnings=found)
    assert not python, [str(w.message) for w in python]
    assert any("regular expression" in p.message and "Possible" in p.message and "escape" in p.message
               for p in found), found


def test_a_regex_python_warns_about_that_selects_nothing_says_why() -> None:
    with pytest.raises(InputError) as caught:
        patterns.select("~x[1&&q]", HOSTS, GROUPS)
    assert "selects no robot" in str(caught.value) and "Possible set intersection" in str(caught.value), caught.value


def test_an_invalid_regex_python_warns_about_is_only_our_error() -> None:
    with warnings.catch_warnings(record=True) as python:
        warnings.simplefilter("always")
        with pytest.raises(InputError, match="invalid regular expression"):
            patterns.select("~r[e--f]", HOSTS, GROUPS)
    assert not python, [str(w.message) for w in python]


# --- item 5: control characters in an @file --------------------------------------------------

def test_an_at_file_line_with_a_control_character_is_refused_unquoted(tmp_path: Path) -> None:
    (tmp_path / "list").write_bytes(b"r1\nr2\0\n")
    (tmp_path / "environ").write_bytes(b"HOME=/root\0SECRET_TOKEN=hunter2\0")
    for name, line in (("list", 2), ("environ", 1)):
        with pytest.raises(InputError) as caught:
            patterns.select(f"@{tmp_path / name}", HOSTS, GROUPS)
        text = str(caught.value)
        assert f"line {line} holds a control character" in text, text
        assert "r2" not in text and "hunter2" not in text and "SECRET_TOKEN" not in text, text


# --- item 2: a thread that cannot be started -------------------------------------------------

def test_status_when_no_thread_can_start_is_an_input_error(capsys: pytest.CaptureFixture, lab: Path,  # noqa: F811
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    real = threading.Thread.start

    def start(self: threading.Thread) -> None:
        if self.name.startswith("robot-"):
            raise RuntimeError("can't start new thread")
        real(self)

    monkeypatch.setattr(threading.Thread, "start", start)
    for command in ("status", "plan"):
        code, text = cli(capsys, lab, command)     # cli() asserts no "internal error"
        assert code == 2, (command, text)
        assert "rollout.forks" in text and "cannot start 2 threads" in text, text



def test_a_run_goes_on_with_the_threads_that_could_start(monkeypatch: pytest.MonkeyPatch) -> None:
    """One thread started, the rest refused: every robot's work is still done, by that one."""
    from rosdeploy import rollout
    real = threading.Thread.start

    def start(self: threading.Thread) -> None:
        if self.name.startswith("robot-") and self.name != "robot-0":
            raise RuntimeError("can't start new thread")
        real(self)

    monkeypatch.setattr(threading.Thread, "start", start)
    futures = rollout._start(list(range(5)), lambda i: i * 10, 4, threading.Event())   # type: ignore[arg-type]
    assert [f.result(timeout=5) for f in futures] == [0, 10, 20, 30, 40]

# --- item 4: render --out with a newline ------------------------------------------------------

def test_render_summary_with_a_newline_in_out_is_one_line(capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    target = lab / "a\nb"
    code = main(["render", str(lab / "fleet.yml"), "--vault-password-file",
                 str(lab / "inventory" / ".vault-password"), "--out", str(target)])
    text = capsys.readouterr().out
    assert code == 0, text
    summary = [line for line in text.splitlines() if "robot(s) to" in line]
    assert len(summary) == 1 and summary[0].endswith("a\\nb/<robot>/"), text
    assert not any(line.startswith("b/") for line in text.splitlines()), text


# --- item 6: a short secret that is one of our words -----------------------------------------

def test_a_wrong_vault_password_that_is_the_word_wrong_is_not_masked_in_our_message(
        capsys: pytest.CaptureFixture, lab: Path) -> None:  # noqa: F811
    """"cannot decrypt: ******** vault password" told the password was `wrong`."""
    (lab / "wrongpw").write_text("wrong\n")
    fleet = str(lab / "fleet.yml")
    code = main(["validate", fleet, "--vault-password-file", str(lab / "wrongpw")])
    text = capsys.readouterr().err
    assert code == 2 and "cannot decrypt: wrong vault password" in text and MASK not in text, text
    code = main(["--json", "validate", fleet, "--vault-password-file", str(lab / "wrongpw")])
    document = json.loads(capsys.readouterr().out)
    assert code == 2 and "cannot decrypt: wrong vault password" in json.dumps(document), document
    assert MASK not in json.dumps(document), document


def test_a_short_secret_is_still_masked_outside_our_wording() -> None:
    import rosdeploy.vault  # noqa: F401  (its message wording is what is read)
    stream = io.StringIO()
    out = Output(stdout=stream, stderr=stream)
    out.mask(["wrong"])
    out.line("error: inventory: cannot decrypt: wrong vault password, or the file was modified; check")
    out.line("+DB_PASSWORD=wrong")
    out.line("robot said: wrong")
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("error: inventory: cannot decrypt: wrong vault password"), lines
    assert lines[1:] == [f"+DB_PASSWORD={MASK}", f"robot said: {MASK}"], lines
    assert out.masked("go wrong vault") == f"go {MASK} vault"      # not a whole piece of our wording


def test_a_secret_equal_to_a_word_of_a_summary_line_is_not_masked_there() -> None:
    """The older leftover: a secret `error` or `robot` masked in our own summaries told it."""
    import rosdeploy.cli.offline  # noqa: F401  (the summaries' wording)
    stream = io.StringIO()
    out = Output(stdout=stream, stderr=stream)
    out.mask(["error", "robot"])
    out.error("3 error(s): not deployable; fix the files above and run validate again")
    out.line("wrote 2 robot(s) to out/<robot>/")
    out.line("robot r1 says error")
    assert stream.getvalue().splitlines() == [
        "3 error(s): not deployable; fix the files above and run validate again",
        "wrote 2 robot(s) to out/<robot>/", f"{MASK} r1 says {MASK}"]
