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
import math
import os
import sys
import time

# The discovery wait counts from here, before rclpy's import and init (~1 s on a busy
# robot): the controller's topics_within is a time since the containers started, not
# since this participant was ready.
ASKED = time.monotonic()
AFTER_INIT_AT_LEAST = 1.0   # s a participant needs to see publishers that are already there


def _message_class(type_name):
    package, _, name = type_name.split("/")   # "sensor_msgs/msg/JointState"
    return getattr(importlib.import_module(package + ".msg"), name)


def _discover(node, rclpy, wanted, deadline):
    """Topic -> types once every wanted topic is on the graph (or the deadline, a monotonic time)."""
    deadline = max(deadline, time.monotonic() + AFTER_INIT_AT_LEAST)
    found = {}
    while time.monotonic() < deadline:
        found = dict(node.get_topic_names_and_types())
        if wanted <= set(found):
            break
        rclpy.spin_once(node, timeout_sec=0.1)
    return found


class _Listener:
    """Each rated topic measured from the moment its publisher is seen, not once the last
    topic appears: a later start level's topic does not hold up the rates of the first's.

    A topic listens up to `window` s from its first message (a new subscription takes a
    moment to match its publisher: counted from the subscription, that moment would be
    missing from the window), less once it has sent more than min_rate * window messages:
    the count only grows, so the full window could not end below min_rate. No message
    within `window` s of subscribing: its rate is 0."""

    def __init__(self, node, topics, window, published):
        self.node, self.topics, self.window, self.published = node, topics, window, published
        self.found, self.stamps, self.since, self.subs = {}, {}, {}, []
        self.enough = {name: math.ceil(rate * window) + 1 for name, rate in topics.items() if rate}

    def look(self, now):
        graph = dict(self.node.get_topic_names_and_types())
        for name in set(self.topics) - set(self.found):
            if name in graph and (not self.published or self.node.count_publishers(name) > 0):
                self.found[name] = graph[name]
                if name in self.enough and self.window > 0:
                    self._subscribe(name, graph[name][0], now)

    def _subscribe(self, name, type_name, now):
        from rclpy.qos import qos_profile_sensor_data  # best effort: matches reliable and best-effort publishers

        self.stamps[name], self.since[name] = [], now
        self.subs.append(self.node.create_subscription(
            _message_class(type_name), name, lambda _msg, n=name: self.stamps[n].append(time.monotonic()),
            qos_profile_sensor_data))

    def measured(self, now):
        return all(len(got) >= self.enough[n] or now >= (got[0] if got else self.since[n]) + self.window
                   for n, got in self.stamps.items())

    def close(self):
        for sub in self.subs:
            self.node.destroy_subscription(sub)
        return {name: _rate(times) for name, times in self.stamps.items()}


def _listen(node, rclpy, topics, deadline, window, published):
    """(topic -> types of what was found, topic -> rate). Ends once every topic was found
    and measured; or at the discovery deadline (a monotonic time) with topics still
    missing, once those found are measured."""
    deadline = max(deadline, time.monotonic() + AFTER_INIT_AT_LEAST)
    listener = _Listener(node, topics, window, published)
    next_look = 0.0
    try:
        while True:
            now = time.monotonic()
            if now >= next_look and len(listener.found) < len(topics):
                listener.look(now)
                next_look = now + 0.1        # a graph query per message would cost a fast topic's CPU
            if listener.measured(now) and (len(listener.found) == len(topics) or now >= deadline):
                break
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        rates = listener.close()
    return listener.found, rates


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
        found, rates = _listen(node, rclpy, topics, ASKED + spec.get("discovery_timeout", 10.0),
                               spec.get("window", 3.0), spec.get("published", False))
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


def _qos_of(node, name):
    """The first publisher's reliability and durability: a transient-local /robot_mode then
    hands over its latched value at once, and a best-effort topic still matches."""
    from rclpy.qos import QoSProfile

    pubs = node.get_publishers_info_by_topic(name)
    qos = QoSProfile(depth=10)
    if pubs:
        qos.reliability = pubs[0].qos_profile.reliability
        qos.durability = pubs[0].qos_profile.durability
    return qos


def _field(msg, path):
    for part in path.split("."):
        msg = getattr(msg, part)
    if hasattr(msg, "tolist"):
        msg = msg.tolist()
    return msg if isinstance(msg, (str, int, float, bool, list)) or msg is None else str(msg)


def _numbers(msg):
    """Every number in a message (Twist: linear.x ... angular.z), for `quiet` (silent or all zero)."""
    if isinstance(msg, (int, float)) and not isinstance(msg, bool):
        return [msg]
    if isinstance(msg, (list, tuple)):
        return [n for m in msg for n in _numbers(m)]
    if hasattr(msg, "get_fields_and_field_types"):
        return [n for f in msg.get_fields_and_field_types() for n in _numbers(getattr(msg, f))]
    return []


def readiness(spec):
    """Readiness conditions: the latest value of a field, or a topic silent/all-zero for N s.
    A field condition waits up to spec["wait"] s for one message; a quiet one listens its N s."""
    import rclpy

    rclpy.init()
    node = rclpy.create_node("rosdeploy_ready_%d" % os.getpid())
    conds = spec["ready"]
    seen = [{} for _ in conds]
    try:
        found = _discover(node, rclpy, {c["topic"] for c in conds}, time.monotonic() + spec.get("wait", 3.0))
        subs = []
        for i, c in enumerate(conds):
            if c["topic"] not in found:
                seen[i] = {"quiet": True, "error": "topic not on the ROS graph"} if "quiet" in c else \
                    {"error": "topic %s not on the ROS graph" % c["topic"]}
                continue
            seen[i] = {"quiet": True} if "quiet" in c else {}
            subs.append(node.create_subscription(_message_class(found[c["topic"]][0]), c["topic"],
                                                 lambda msg, i=i, c=c: _note(seen[i], c, msg),
                                                 _qos_of(node, c["topic"])))
        start = time.monotonic()
        wait = spec.get("wait", 3.0)

        def pending():
            now = time.monotonic() - start
            return any(("quiet" in c and now < c["quiet"] and seen[i].get("quiet"))
                       or ("quiet" not in c and "value" not in seen[i] and "error" not in seen[i] and now < wait)
                       for i, c in enumerate(conds))
        while pending():
            rclpy.spin_once(node, timeout_sec=0.05)
        for i, c in enumerate(conds):
            if "quiet" not in c and "value" not in seen[i] and "error" not in seen[i]:
                seen[i] = {"error": "no message within %gs" % wait}
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return seen


def _note(entry, cond, msg):
    if "quiet" in cond:
        if any(n != 0 for n in _numbers(msg)):
            entry["quiet"] = False
            entry["value"] = _numbers(msg)[:6]
        return
    try:
        entry["value"] = _field(msg, cond["field"])
    except AttributeError:
        entry["error"] = "message has no field %s" % cond["field"]


def main():
    spec = json.loads(sys.argv[1])
    if "ready" in spec:
        print(json.dumps({"ready": readiness(spec)}, sort_keys=True))
        return 0
    report = probe(spec)
    print(json.dumps({"topics": report, "domain": os.environ.get("ROS_DOMAIN_ID")}, sort_keys=True))
    return 0 if all(t["ok"] for t in report.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
