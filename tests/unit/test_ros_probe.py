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


def test_measuring_stops_once_the_count_proves_every_min_rate() -> None:
    began = time.monotonic()
    rates = ros_probe._measure(FakeNode(), FakeRclpy, {"/a": 5.0, "/b": 2.0}, {"/a": ["t"], "/b": ["t"]}, 3.0)
    assert time.monotonic() - began < 1.5          # 17 messages at ~100 Hz, not the 3 s window
    assert all(rate > 5.0 for rate in rates.values())


def test_a_topic_below_its_min_rate_is_measured_for_the_whole_window() -> None:
    began = time.monotonic()
    rates = ros_probe._measure(FakeNode(), FakeRclpy, {"/fast": 1000.0}, {"/fast": ["t"]}, 0.3)
    assert time.monotonic() - began >= 0.3
    assert 0 < rates["/fast"] < 1000.0


class GraphNode(FakeNode):
    """/watched has only a subscriber (an image's health watcher); /published has a publisher."""

    def get_topic_names_and_types(self):
        return [("/watched", ["std_msgs/msg/String"]), ("/published", ["std_msgs/msg/String"])]

    def count_publishers(self, name: str) -> int:
        return 1 if name == "/published" else 0


def test_a_topic_with_only_subscribers_is_not_found_when_publishers_count(monkeypatch) -> None:
    monkeypatch.setattr(ros_probe, "AFTER_INIT_AT_LEAST", 0.0)
    found = ros_probe._discover(GraphNode(), FakeRclpy, {"/watched", "/published"}, time.monotonic() + 0.2,
                                published=True)
    assert "/published" in found and "/watched" not in found
    found = ros_probe._discover(GraphNode(), FakeRclpy, {"/watched"}, time.monotonic() + 0.2)
    assert {"/watched", "/published"} <= set(found)


def test_discovery_ends_at_its_deadline_but_listens_a_moment_after_init(monkeypatch) -> None:
    """The deadline counts from when the probe was asked; a slow rclpy init that used it up
    still leaves the participant AFTER_INIT_AT_LEAST to see what is there."""
    monkeypatch.setattr(ros_probe, "AFTER_INIT_AT_LEAST", 0.3)
    began = time.monotonic()
    ros_probe._discover(GraphNode(), FakeRclpy, {"/missing"}, began - 5.0)
    assert 0.3 <= time.monotonic() - began < 1.0
    began = time.monotonic()
    ros_probe._discover(GraphNode(), FakeRclpy, {"/missing"}, began + 0.6)
    assert 0.6 <= time.monotonic() - began < 1.2
