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
    ("site_north,site_south:!amr-s2", ["amr-n1", "amr-n2", "amr-s1"]),
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


def test_every_unknown_term_is_reported():
    with pytest.raises(InventoryError) as caught:
        names("nope1:&nope2")
    assert len(caught.value.problems) == 2


def test_empty_result_is_an_error_naming_the_pattern():
    with pytest.raises(InventoryError, match="'site_north:&site_south' selects no robot"):
        names("site_north:&site_south")


def test_empty_pattern_and_bad_regex():
    with pytest.raises(InventoryError, match="empty"):
        names(" , ")
    with pytest.raises(InventoryError, match="invalid regular expression"):
        names("~amr-(")


def test_split_keeps_brackets_whole():
    assert split("web[0:2]:db,~x.*:!y") == ["web[0:2]", "db", "~x.*", "!y"]
