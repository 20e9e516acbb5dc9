"""The ROS graph probe rosdeploy runs INSIDE a container of the release.

This file is not imported by rosdeploy: its source is sent to the robot and run
with `python3 -c SOURCE SPEC_JSON` in a container that has rclpy, so it sees
the robot's ROS graph on the release's own ROS_DOMAIN_ID and RMW. It must stay
self-contained (stdlib + rclpy) and cheap: one participant, one discovery
wait, one measuring window (cut short once the counts prove the rates), then
exit. Prints one JSON line; exit 0 = healthy.
"""
import importlib
import json
import os
import sys
import time


def _message_class(type_name):
    package, _, name = type_name.split("/")   # "sensor_msgs/msg/JointState"
    return getattr(importlib.import_module(package + ".msg"), name)


def _discover(node, rclpy, wanted, timeout):
    deadline = time.monotonic() + timeout
    found = {}
    while time.monotonic() < deadline:
        found = dict(node.get_topic_names_and_types())
        if wanted <= set(found):
            break
        rclpy.spin_once(node, timeout_sec=0.1)
    return found


def _measure(node, rclpy, topics, found, window):
    """topics: name -> min_rate. Listens up to `window` seconds, less once every topic
    has sent more than min_rate * window messages: the count only grows, so the full
    window could not end below min_rate any more."""
    from rclpy.qos import qos_profile_sensor_data  # best effort: matches reliable and best-effort publishers

    stamps = {name: [] for name in topics}
    enough = {name: int(rate * window) + 2 for name, rate in topics.items()}
    subs = [node.create_subscription(_message_class(found[name][0]), name,
                                     lambda _msg, n=name: stamps[n].append(time.monotonic()),
                                     qos_profile_sensor_data)
            for name in topics]
    deadline = time.monotonic() + window
    while time.monotonic() < deadline and any(len(stamps[n]) < enough[n] for n in topics):
        rclpy.spin_once(node, timeout_sec=0.05)
    for sub in subs:
        node.destroy_subscription(sub)
    return {name: _rate(times) for name, times in stamps.items()}


def _rate(times):
    if len(times) < 2:
        return 0.0
    return (len(times) - 1) / max(times[-1] - times[0], 1e-6)


def probe(spec):
    import rclpy

    rclpy.init()
    node = rclpy.create_node("rosdeploy_probe_%d" % os.getpid())
    try:
        topics = {t["name"]: t.get("min_rate") for t in spec["topics"]}
        found = _discover(node, rclpy, set(topics), spec.get("discovery_timeout", 10.0))
        rated = {n: r for n, r in topics.items() if r and n in found}
        rates = _measure(node, rclpy, rated, found, spec.get("window", 3.0)) if rated else {}
    finally:
        node.destroy_node()
        rclpy.shutdown()
    report = {}
    for name, min_rate in topics.items():
        entry = {"present": name in found, "min_rate": min_rate}
        if name in rates:
            entry["rate"] = round(rates[name], 2)
        entry["ok"] = entry["present"] and (not min_rate or entry.get("rate", 0.0) >= min_rate)
        report[name] = entry
    return report


def main():
    report = probe(json.loads(sys.argv[1]))
    print(json.dumps({"topics": report, "domain": os.environ.get("ROS_DOMAIN_ID")}, sort_keys=True))
    return 0 if all(t["ok"] for t in report.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
