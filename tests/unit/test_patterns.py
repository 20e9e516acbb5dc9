"""Ansible host patterns over plain names."""
from __future__ import annotations

import pytest

from rosdeploy.errors import InventoryError
from rosdeploy.patterns import select, split

HOSTS = ("amr-n1", "amr-n2", "amr-s1", "amr-s2", "bench-1")
GROUPS = {
    "all": HOSTS,
    "warehouse": ("amr-n1", "amr-n2", "amr-s1", "amr-s2"),
    "site_north": ("amr-n1", "amr-n2"),
    "site_south": ("amr-s1", "amr-s2"),
    "perception": ("amr-n1", "amr-s2"),
    "retired": (),
}


def names(pattern: str | None) -> list[str]:
    return list(select(pattern, HOSTS, GROUPS))


@pytest.mark.parametrize("pattern, expected", [
    (None, list(HOSTS)),
    ("all", list(HOSTS)),
    ("*", list(HOSTS)),
    ("amr-s1", ["amr-s1"]),
    ("site_south", ["amr-s1", "amr-s2"]),
    ("amr-s*", ["amr-s1", "amr-s2"]),
    ("amr-?1", ["amr-n1", "amr-s1"]),
    ("site_*", ["amr-n1", "amr-n2", "amr-s1", "amr-s2"]),       # globs match group names too
    ("~amr-[ns]2", ["amr-n2", "amr-s2"]),
    ("~bench", ["bench-1"]),                                    # regex anchored at the start only
    ("~n1", []),                                                # ... so this matches nothing (error below)
])
def test_single_terms(pattern, expected):
    if not expected:
        with pytest.raises(InventoryError):
            names(pattern)
        return
    assert names(pattern) == expected


@pytest.mark.parametrize("pattern, expected", [
    ("site_south:amr-n1", ["amr-n1", "amr-s1", "amr-s2"]),       # union, inventory order kept
    ("site_south,amr-n1", ["amr-n1", "amr-s1", "amr-s2"]),
    ("warehouse:&perception", ["amr-n1", "amr-s2"]),             # intersection
    ("warehouse:!perception", ["amr-n2", "amr-s1"]),             # exclusion
    ("!perception", ["amr-n2", "amr-s1", "bench-1"]),            # only exclusions: from all
    ("&site_north", ["amr-n1", "amr-n2"]),
    # Ansible's order: unions, then intersections, then exclusions, whatever the writing order.
    ("!amr-n1:site_north:bench-1", ["amr-n2", "bench-1"]),
    ("&perception:site_north:site_south", ["amr-n1", "amr-s2"]),
    ("site_north:&perception:!amr-n1:site_south", ["amr-s2"]),
    ("warehouse:!~amr-s.*", ["amr-n1", "amr-n2"]),
    # With a comma, Ansible splits on commas only: `site_south:!amr-s2` is one term matching nothing.
    ("site_north,site_south:!amr-s2", ["amr-n1", "amr-n2"]),
    ("warehouse[0]", ["amr-n1"]),                                 # subscripts, Ansible's inclusive end
    ("warehouse[-1]", ["amr-s2"]),
    ("warehouse[1:2]", ["amr-n2", "amr-s1"]),
    ("warehouse[2:]", ["amr-s1", "amr-s2"]),
    ("site_north[0]:site_south[-1]", ["amr-n1", "amr-s2"]),
    (" site_north , amr-s1 ", ["amr-n1", "amr-n2", "amr-s1"]),    # spaces around terms
])
def test_operators(pattern, expected):
    assert names(pattern) == expected


def test_empty_group_is_a_known_name_not_an_error():
    assert names("warehouse:!retired") == ["amr-n1", "amr-n2", "amr-s1", "amr-s2"]


def test_unknown_term_is_an_error_even_inside_an_exclusion():
    # Ansible only warns; deploying to the robot one meant to exclude is worse.
    with pytest.raises(InventoryError) as caught:
        names("all:!amr-n9")
    assert "'amr-n9' matches no host or group" in str(caught.value)
    assert "did you mean 'amr-n" in str(caught.value)


def test_every_unknown_exclusion_is_reported():
    with pytest.raises(InventoryError) as caught:
        names("site_north:!nope2:!nope3")
    assert len(caught.value.problems) == 2


def test_an_unmatched_union_term_is_a_warning_as_in_ansible():
    warnings: list = []
    assert list(select("site_north:nomatch", HOSTS, GROUPS, warnings=warnings)) == ["amr-n1", "amr-n2"]
    assert len(warnings) == 1 and warnings[0].severity == "warning" and "'nomatch'" in warnings[0].message


def test_a_pattern_matching_nothing_at_all_is_refused_with_the_reason():
    with pytest.raises(InventoryError, match="'nope' matches no host or group"):
        names("nope")


def test_localhost_is_refused_unless_the_inventory_has_it():
    with pytest.raises(InventoryError, match="localhost is not in the inventory"):
        names("localhost")
    assert list(select("localhost", (*HOSTS, "localhost"), GROUPS)) == ["localhost"]


def test_subscripts_index_the_group_order_given_not_the_inventory_order():
    groups = {**GROUPS, "canary": ("amr-s2", "amr-n1")}
    assert names_in(groups, "canary[0]") == ["amr-s2"]
    assert names_in(groups, "canary[0:0]") == ["amr-s2"]      # Ansible reads an end of 0 as none


def names_in(groups, pattern):
    return list(select(pattern, HOSTS, groups))


def test_empty_result_is_an_error_naming_the_pattern():
    with pytest.raises(InventoryError, match="'site_north:&site_south' selects no robot"):
        names("site_north:&site_south")


def test_empty_pattern_and_bad_regex():
    with pytest.raises(InventoryError, match="empty"):
        names(" , ")
    for unclosed in ("[", "[[", ":["):      # no term survives the split: not called empty
        with pytest.raises(InventoryError, match=r"names no host or group \(a `\[` without its `\]`\?\)"):
            names(unclosed)
    with pytest.raises(InventoryError, match="invalid regular expression"):
        names("~amr-(")


def test_split_like_ansible():
    assert split("web[0:2]:db:~x.*:!y") == ["web[0:2]", "db", "~x.*", "!y"]
    assert split("a:b,c") == ["a:b", "c"]      # a comma present: split on commas only
    assert split("amr-n1:22") == ["amr-n1:22"]  # host:port is one address


def test_a_backtracking_regex_is_stopped_and_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """`~(a+)+b` against a long name backtracks exponentially in `re` (as in Ansible): here about
    9 s unbounded; the budget stops it with an input error that says what to do."""
    import time

    from rosdeploy import patterns
    monkeypatch.setattr(patterns, "REGEX_BUDGET", 0.2)
    began = time.monotonic()
    with pytest.raises(InventoryError, match=r"'~\(a\+\)\+b' took more than 0.2 s .* simplify the regex"):
        select("~(a+)+b", (*HOSTS, "a" * 28), GROUPS)
    assert time.monotonic() - began < 2
    assert names("~amr-[ns]1") == ["amr-n1", "amr-s1"]      # the timer and handler are gone afterwards


@pytest.mark.parametrize("pattern", ["~amr-n[", "~amr-n[:bench-1", "bench-1:~amr-n[", "bench-1,~amr-n["])
def test_an_unclosed_bracket_in_a_regex_is_refused_not_dropped(pattern: str) -> None:
    """Ansible's ':' split drops the stray `[`, so `~amr-n[` selected every amr-n robot."""
    with pytest.raises(InventoryError, match=r"invalid regular expression '~amr-n\[': unterminated character set"):
        names(pattern)


def test_a_stray_bracket_in_a_name_is_refused() -> None:
    with pytest.raises(InventoryError, match=r"'site_north\]:bench-1' has a `\[` or `\]` without its pair"):
        names("site_north]:bench-1")
    assert names("~amr-[n]1:~bench-[1]") == ["amr-n1", "bench-1"]      # paired brackets are fine


# ---------------------------------------------------------- issue 18: hostile --limit values

@pytest.mark.parametrize("subscript", ["9" * 5000, "1:" + "9" * 5000, "9" * 5000 + ":", "-" + "9" * 5000,
                                       "1" + "0" * 18], ids=["index", "end", "start", "negative", "19 digits"])
def test_a_subscript_of_absurd_digits_is_refused_cleanly(subscript: str) -> None:
    # int() of 4300+ digits raised ValueError (exit 1); Ansible fails there with "probably a bug".
    with pytest.raises(InventoryError, match="past any inventory"):
        names(f"warehouse[{subscript}]")


def test_a_subscript_past_the_group_selects_nothing_but_a_long_slice_runs_to_the_end() -> None:
    # As Ansible (checked with ansible --list-hosts): `web[1:99]` is w2, `web[5]` nothing.
    assert names("warehouse[2:" + "9" * 18 + "]") == ["amr-s1", "amr-s2"]
    assert names("warehouse[" + "9" * 18 + "]:bench-1") == ["bench-1"]


def test_an_at_file_is_read_one_pattern_a_line(tmp_path) -> None:
    limit = tmp_path / "lim.txt"
    limit.write_text("amr-n1\n\n  site_south \n")
    assert names(f"@{limit}") == ["amr-n1", "amr-s1", "amr-s2"]
    assert names(f"@{limit}:!amr-s2") == ["amr-n1", "amr-s1"]


@pytest.mark.parametrize("make, match", [
    (lambda p: p / "missing.txt", "unable to find limit file"),
    (lambda p: p, "not a regular file"),
    (lambda p: (p / "big.txt").write_text("a\n" * (1 << 20)) and p / "big.txt", "larger than 1 MB"),
    (lambda p: (p / "bin.txt").write_bytes(b"\xff\xfe") and p / "bin.txt", "not UTF-8"),
    (lambda p: (p / "br.txt").write_text("amr-n1]\n") and p / "br.txt", "without its pair"),
])
def test_a_bad_at_file_is_a_clean_error(tmp_path, make, match: str) -> None:
    with pytest.raises(InventoryError, match=match):
        names(f"@{make(tmp_path)}")
