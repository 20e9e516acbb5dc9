"""The probe's measuring loop, with a fake rclpy (the real one runs in tests/integration)."""
from __future__ import annotations

import sys
import time
import types

import pytest

from rosdeploy import ros_probe


class FakeNode:
    def __init__(self) -> None:
        self.callbacks: list = []

    def create_subscription(self, _type, _name, callback, _qos):
        self.callbacks.append(callback)
        return callback

    def destroy_subscription(self, _sub) -> None:
        pass


class FakeRclpy:
    """Every spin delivers one message per subscription, 100 per second."""

    @staticmethod
    def spin_once(node: FakeNode, timeout_sec: float) -> None:
        time.sleep(0.01)
        for callback in node.callbacks:
            callback(object())


@pytest.fixture(autouse=True)
def no_message_types(monkeypatch) -> None:
    monkeypatch.setattr(ros_probe, "_message_class", lambda _t: object)
    qos = types.ModuleType("rclpy.qos")
    qos.qos_profile_sensor_data = None
    monkeypatch.setitem(sys.modules, "rclpy", types.ModuleType("rclpy"))
    monkeypatch.setitem(sys.modules, "rclpy.qos", qos)


class GraphNode(FakeNode):
    """/watched has only a subscriber (an image's health watcher); /a, /b and /published
    have publishers. `late`: topic -> monotonic time it appears on the graph."""

    def __init__(self, late: dict[str, float] | None = None) -> None:
        super().__init__()
        self.late = late or {}
        self.subscribed: dict[str, float] = {}

    def get_topic_names_and_types(self):
        now = time.monotonic()
        return [(n, ["std_msgs/msg/String"]) for n in ("/watched", "/published", "/a", "/b", "/fast")
                if self.late.get(n, 0.0) <= now]

    def count_publishers(self, name: str) -> int:
        return 0 if name == "/watched" else 1

    def create_subscription(self, _type, name, callback, _qos):
        self.subscribed[name] = time.monotonic()
        return super().create_subscription(_type, name, callback, _qos)


def listen(node: GraphNode, topics: dict, deadline: float = 5.0, window: float = 3.0, published: bool = True):
    return ros_probe._listen(node, FakeRclpy, topics, time.monotonic() + deadline, window, published)


def test_measuring_stops_once_the_count_proves_every_min_rate() -> None:
    began = time.monotonic()
    found, rates = listen(GraphNode(), {"/a": 5.0, "/b": 2.0})
    assert time.monotonic() - began < 1.5          # 16 messages at ~100 Hz, not the 3 s window
    assert {"/a", "/b"} <= set(found) and all(rate > 5.0 for rate in rates.values())


def test_the_fewest_messages_that_prove_a_rate_over_the_window() -> None:
    """n messages within the window span at most the window: (n - 1) / window >= min_rate."""
    listener = ros_probe._Listener(GraphNode(), {"/a": 2.0, "/b": 2.5, "/c": None}, 3.0, True)
    assert listener.enough == {"/a": 7, "/b": 9}


def test_a_topic_below_its_min_rate_is_measured_for_the_whole_window() -> None:
    began = time.monotonic()
    _, rates = listen(GraphNode(), {"/fast": 1000.0}, window=0.3)
    assert time.monotonic() - began >= 0.3
    assert 0 < rates["/fast"] < 1000.0


def test_a_topic_is_measured_from_when_it_appears_not_when_the_last_one_does() -> None:
    """A later start level's topic (/b) must not hold up the measuring of the first's (/a)."""
    node = GraphNode(late={"/b": time.monotonic() + 0.4})
    found, rates = listen(node, {"/a": 5.0, "/b": 2.0})
    assert node.subscribed["/a"] < node.late["/b"] <= node.subscribed["/b"]
    assert set(rates) == {"/a", "/b"} and {"/a", "/b"} <= set(found)


def test_a_topic_with_only_subscribers_is_not_found_when_publishers_count(monkeypatch) -> None:
    monkeypatch.setattr(ros_probe, "AFTER_INIT_AT_LEAST", 0.0)
    found, _ = listen(GraphNode(), {"/watched": None, "/published": None}, deadline=0.2)
    assert "/published" in found and "/watched" not in found
    found, _ = listen(GraphNode(), {"/watched": None}, deadline=0.2, published=False)
    assert "/watched" in found


def test_a_missing_topic_ends_the_listening_at_the_deadline_once_the_others_are_measured(monkeypatch) -> None:
    monkeypatch.setattr(ros_probe, "AFTER_INIT_AT_LEAST", 0.0)
    began = time.monotonic()
    found, rates = listen(GraphNode(), {"/missing": None, "/a": 5.0}, deadline=0.3, window=10.0)
    assert 0.3 <= time.monotonic() - began < 1.5
    assert "/missing" not in found and rates["/a"] > 5.0


def test_discovery_ends_at_its_deadline_but_listens_a_moment_after_init(monkeypatch) -> None:
    """The deadline counts from when the probe was asked; a slow rclpy init that used it up
    still leaves the participant AFTER_INIT_AT_LEAST to see what is there."""
    monkeypatch.setattr(ros_probe, "AFTER_INIT_AT_LEAST", 0.3)
    for ends_in, at_least in ((-5.0, 0.3), (0.6, 0.6)):
        for find in (ros_probe._discover, None):
            began = time.monotonic()
            if find:
                find(GraphNode(), FakeRclpy, {"/missing"}, began + ends_in)
            else:
                listen(GraphNode(), {"/missing": None}, deadline=ends_in)
            assert at_least <= time.monotonic() - began < at_least + 0.6


class LateRclpy(FakeRclpy):
    """The subscriptions match their publishers only at `matched` (a monotonic time)."""
    matched = 0.0

    @classmethod
    def spin_once(cls, node: FakeNode, timeout_sec: float) -> None:
        if time.monotonic() >= cls.matched:
            FakeRclpy.spin_once(node, timeout_sec)
        else:
            time.sleep(0.01)


def test_the_window_counts_from_the_first_message_not_from_subscribing(monkeypatch) -> None:
    monkeypatch.setattr(LateRclpy, "matched", time.monotonic() + 0.25)
    began = time.monotonic()
    _, rates = ros_probe._listen(GraphNode(), LateRclpy, {"/fast": 1000.0}, began + 5.0, 0.3, True)
    assert time.monotonic() - began >= 0.55         # 0.25 s to match, then the whole 0.3 s window
    assert 50.0 < rates["/fast"] < 1000.0


def test_a_topic_that_never_sends_has_rate_zero_one_window_after_subscribing(monkeypatch) -> None:
    monkeypatch.setattr(LateRclpy, "matched", time.monotonic() + 60.0)
    began = time.monotonic()
    found, rates = ros_probe._listen(GraphNode(), LateRclpy, {"/a": 5.0}, began + 5.0, 0.3, True)
    assert 0.3 <= time.monotonic() - began < 1.0
    assert "/a" in found and rates["/a"] == 0.0
