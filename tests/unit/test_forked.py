"""forked.mapped: the serial loop's results and exceptions, whatever a child does."""
from __future__ import annotations

import os
import signal
import threading
from pathlib import Path

import pytest
import yaml

from rosdeploy import checks, forked
from rosdeploy.project import load_project, prepare

PARENT = os.getpid()


@pytest.fixture
def forking(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fork from 4 items on, into up to 3 processes, whatever this machine's cores, and even if an
    earlier test of the session left a thread behind (can_fork would refuse then)."""
    monkeypatch.setattr(forked, "MIN_ITEMS", 4)
    monkeypatch.setattr(forked.os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    monkeypatch.setattr(forked, "can_fork", lambda: True)


def in_child() -> bool:
    return os.getpid() != PARENT


def square(n: int) -> tuple[int, int]:
    return n * n, os.getpid()


def test_results_come_in_order_and_children_computed_some(forking: None) -> None:
    out = list(forked.mapped(square, list(range(40))))
    assert [value for value, _ in out] == [n * n for n in range(40)]
    pids = {pid for _, pid in out}
    assert PARENT in pids and len(pids) == 3


def test_too_few_items_or_another_thread_is_the_serial_loop(forking: None, monkeypatch: pytest.MonkeyPatch) -> None:
    assert {pid for _, pid in forked.mapped(square, [1, 2, 3])} == {PARENT}
    monkeypatch.undo()
    monkeypatch.setattr(forked, "MIN_ITEMS", 4)
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert forked.workers(40) == 1
        assert {pid for _, pid in forked.mapped(square, list(range(40)))} == {PARENT}
    finally:
        stop.set()
        other.join()


def fails_in_child_on_30(n: int) -> int:
    if n == 30 and in_child():
        raise ValueError("only in the child")
    return n + 1


def test_a_child_that_fails_is_recomputed_here(forking: None) -> None:
    assert list(forked.mapped(fails_in_child_on_30, list(range(40)))) == [n + 1 for n in range(40)]


def killed_in_child(n: int) -> int:
    if n == 35 and in_child():
        os.kill(os.getpid(), signal.SIGKILL)
    return -n


def test_a_child_killed_by_a_signal_is_recomputed_here(forking: None) -> None:
    assert list(forked.mapped(killed_in_child, list(range(40)))) == [-n for n in range(40)]


def unpicklable_in_child(n: int) -> object:
    return (lambda: n) if in_child() else n


def test_a_result_that_does_not_pickle_is_recomputed_here(forking: None) -> None:
    assert list(forked.mapped(unpicklable_in_child, list(range(40)))) == list(range(40))


def fails_on_33(n: int) -> int:
    if n == 33:
        raise KeyError(n)
    return n


def test_an_exception_is_the_one_the_serial_loop_raises(forking: None) -> None:
    before = _children()
    with pytest.raises(KeyError, match="33"):
        list(forked.mapped(fails_on_33, list(range(40))))
    assert _children() <= before


def test_stopping_early_leaves_no_child(forking: None) -> None:
    before = _children()
    results = forked.mapped(square, list(range(4000)))
    assert next(results)[0] == 0
    assert _children() - before, "no child was started: the test would prove nothing"
    results.close()
    assert _children() <= before


def _children() -> set[int]:
    """Processes whose parent is this one (zombies included: a child not waited for); earlier
    tests of the session may have left their own."""
    mine = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == PARENT:
                mine.add(int(entry.name))
    return mine


# ------------------------------------------------------- rendering a fleet

def fleet(root: Path, robots: int) -> Path:
    """`robots` robots; every third defines `tag`, which an environment value reads: the others fail."""
    hosts = {f"r{i:03d}": {"ansible_host": f"10.0.{i // 200}.{i % 200 + 1}", "ros_domain_id": i % 100,
                           "ros_network": f"net{i // 100}", **({"tag": f"t{i}"} if i % 3 == 0 else {}),
                           # every other one by a name that changes across boots: a warning naming robots
                           "devices": {"cam": "/dev/video0" if i % 2 else "/dev/robot/cam"}}
             for i in range(robots)}
    (root / "inventory").mkdir(parents=True)
    (root / "inventory" / "hosts.yml").write_text(yaml.safe_dump({"all": {"hosts": hosts}}))
    (root / "fleet.yml").write_text(yaml.safe_dump({
        "project": "lab", "inventory": "./inventory", "registry": "registry.local:5000", "version": "1.0.0",
        "services": {"driver": {"image": "lab/driver", "user": "1000:1000",
                                "devices": ["cam"],
                                "environment": {"TAG": "{{ tag }}", "NAME": "{{ inventory_hostname }}"}},
                     "camera": {"image": "lab/camera", "devices": ["cam"]}}}))
    return root / "fleet.yml"


def outcome(path: Path) -> tuple[dict[str, str], list[str]]:
    project = load_project(str(path))
    releases, problems = prepare(project, project.targets())
    # the release rules ran where each robot rendered: the same as running every rule afterwards
    hosts = project.targets()
    afterwards = checks.run_checks(project.spec, hosts, releases, all_hosts=hosts)
    assert [p for p in problems if p.rule] == afterwards
    return {name: r.digest for name, r in releases.items()}, [str(p) for p in problems]


def test_rendering_in_children_gives_what_one_process_gives(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                            forking: None) -> None:
    path = fleet(tmp_path, 60)
    sent = []
    monkeypatch.setattr(forked, "_Child", _counting(forked._Child, sent))
    forked_releases, forked_problems = outcome(path)
    assert sent, "no child rendered: the test would prove nothing"
    monkeypatch.setattr(forked, "MIN_ITEMS", 10**9)
    assert outcome(path) == (forked_releases, forked_problems)
    assert list(forked_releases) == [f"r{i:03d}" for i in range(0, 60, 3)]
    assert any("'tag'" in p and "(the same on 39 more robot(s))" in p for p in forked_problems)
    assert any("/dev/video0 on 'r003', 'r009', 'r015', 'r021', 'r027' (+5 more)" in p for p in forked_problems)


def _counting(cls: type, sent: list) -> type:
    class Counting(cls):  # type: ignore[valid-type,misc]
        def __init__(self, func, part) -> None:  # noqa: ANN001
            sent.append(len(part))
            super().__init__(func, part)
    return Counting
