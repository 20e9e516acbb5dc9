"""Whether a lock's holder is provably dead: only a run of this very system can be judged."""
from __future__ import annotations

import json
import os

import pytest

from rosdeploy.owner import Controller, dead_run, pid_alive, record, this_controller

HERE = Controller(boot="b1", pid_namespace="pid:[4026531836]")


def holder(**fields: object) -> str:
    return json.dumps({**record("run-A", "ops@laptop", "2026-11-22T10:00:00+00:00", HERE, 4242), **fields})


def never(_pid: int) -> bool:
    raise AssertionError("a pid of another boot or namespace must not be looked up here")


@pytest.mark.parametrize("text,alive,expected", [
    (holder(), lambda pid: False, ("run-A", "its process 4242 on this machine is gone")),
    (holder(), lambda pid: True, None),                                  # still running (or reused)
    (holder(boot="b0"), never, None),             # rebooted since, or a cloned machine: cannot tell
    (holder(pid_namespace="pid:[4026532000]"), never, None),             # a container's run
    (holder(pid=True), never, None), (holder(pid="4242"), never, None),
    (json.dumps({"run": "run-A", "by": "alice@ops", "pid": 4242}), never, None),   # an older record
    ('{"by": "alice@ops"}', never, None),                                # hand-made, no run id
    ("held by somebody", never, None),                                   # not JSON
    ("[1, 2]", never, None),
])
def test_only_a_run_of_this_system_that_is_gone_is_dead(text: str, alive, expected) -> None:
    assert dead_run(text, HERE, alive) == expected


def test_a_system_that_cannot_name_itself_judges_nothing() -> None:
    blind = Controller(boot=None, pid_namespace=None)
    assert dead_run(json.dumps(record("run-A", "me", "now", blind, 4242)), blind, lambda pid: False) is None


def test_this_process_is_alive_and_an_unused_pid_is_not() -> None:
    assert pid_alive(os.getpid())
    assert not pid_alive(2 ** 22 + 1)        # above Linux's pid_max limit: never a process


def test_this_system_names_itself_as_it_reads_the_record_back() -> None:
    here = this_controller()
    assert here.boot and here.pid_namespace and here == this_controller()
    assert dead_run(json.dumps(record("run-B", "me@here", "now", here, os.getpid())), here) is None
