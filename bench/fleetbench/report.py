"""Medians, the side-by-side table, the targets, the JSON record and the docs section."""
from __future__ import annotations

import json
import os
import platform
import re
import statistics
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from fleetbench.scenarios import FLOOR, FLOOR_ORDERED, SCENARIOS, SSH_FLOOR, TITLES, Measure

BEGIN, END = "<!-- fleet_bench:begin -->", "<!-- fleet_bench:end -->"


@dataclass(frozen=True)
class Goal:
    name: str
    text: str
    value: float | None     # what was measured (speedup, or seconds for status)
    threshold: float
    higher_is_better: bool

    @property
    def met(self) -> bool | None:
        if self.value is None:
            return None
        return self.value >= self.threshold if self.higher_is_better else self.value < self.threshold


def median(values: Iterable[float]) -> float | None:
    values = list(values)
    return statistics.median(values) if values else None


def speedup(ours: float | None, theirs: float | None) -> float | None:
    return theirs / ours if ours and theirs else None


# ------------------------------------------------------------- step profile

def step_names(steps: Sequence[Mapping[str, Any]]) -> list[tuple[str, float]]:
    """("start", s), ("health", s), ("start#2", s)...: a release id is dropped, repeats are numbered."""
    seen: dict[str, int] = defaultdict(int)
    named = []
    for step in steps:
        base = step["name"].split(" ", 1)[0]
        seen[base] += 1
        named.append((base if seen[base] == 1 else f"{base}#{seen[base]}", float(step["seconds"])))
    return named


def step_medians(measures: Sequence[Measure]) -> dict[str, float]:
    """Per step: the median over every robot of every round (robots that ran the step)."""
    by_step: dict[str, list[float]] = defaultdict(list)
    order: list[str] = []
    for measure in measures:
        for host in measure.steps:
            for name, seconds in step_names(host["steps"]):
                by_step[name].append(seconds)
                if name not in order:
                    order.append(name)
    return {name: round(statistics.median(by_step[name]), 3) for name in order}


def overhead(measures: Sequence[Measure]) -> float | None:
    """Wall time outside the rollout itself: interpreter, imports, load, render, run log."""
    return median(m.seconds - m.wall_inside for m in measures if m.wall_inside is not None)


# ----------------------------------------------------------------- results

def fleet_section(rounds: Mapping[str, Sequence[Mapping[str, Measure]]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for scenario in SCENARIOS:
        if not any(scenario in r for series in rounds.values() for r in series):
            continue     # not selected (--scenarios)
        ours = [r[scenario] for r in rounds.get("rosdeploy", ())]
        theirs = [r[scenario] for r in rounds.get("ansible", ())]
        minimal = [r[scenario] for r in rounds.get("ansible-minimal", ())]
        at_once = [r[scenario] for r in rounds.get("rosdeploy-at-once", ())]
        floor = [r[scenario] for r in rounds.get(FLOOR, ()) if scenario in r]     # none for the bad release
        ordered = [r[scenario] for r in rounds.get(FLOOR_ORDERED, ()) if scenario in r]
        entry: dict[str, Any]
        entry = {"title": TITLES[scenario],
                 "rosdeploy": [round(m.seconds, 3) for m in ours], "ansible": [round(m.seconds, 3) for m in theirs],
                 "ansible_minimal": [round(m.seconds, 3) for m in minimal],
                 "rosdeploy_at_once": [round(m.seconds, 3) for m in at_once],
                 "rosdeploy_at_once_median": _r(median(m.seconds for m in at_once)),
                 "rosdeploy_median": _r(median(m.seconds for m in ours)),
                 "ansible_median": _r(median(m.seconds for m in theirs)),
                 "ansible_minimal_median": _r(median(m.seconds for m in minimal)),
                 "floor": [round(m.seconds, 3) for m in floor],
                 "floor_median": _r(median(m.seconds for m in floor)),
                 "floor_ordered": [round(m.seconds, 3) for m in ordered],
                 "floor_ordered_median": _r(median(m.seconds for m in ordered))}
        entry["speedup"] = _r(speedup(entry["rosdeploy_median"], entry["ansible_median"]), 2)
        ssh_floor = [r[scenario] for r in rounds.get(SSH_FLOOR, ()) if scenario in r]
        if ssh_floor and entry["rosdeploy_median"] is not None:
            entry["ssh_floor"] = [round(m.seconds, 3) for m in ssh_floor]
            entry["ssh_floor_median"] = _r(median(m.seconds for m in ssh_floor))
            entry["above_ssh_floor"] = _r(entry["rosdeploy_median"] - entry["ssh_floor_median"])
        # Issue #19 states its targets as rosdeploy's time over the minimal playbook's.
        entry["ratio_minimal"] = _r(speedup(entry["ansible_minimal_median"], entry["rosdeploy_median"]), 2)
        entry["ratio_equal_work"] = _r(speedup(entry["ansible_median"], entry["rosdeploy_median"]), 2)
        # The same shape as minimal.yml: every robot at once (the demo fleet deploys a canary first).
        entry["ratio_minimal_at_once"] = _r(speedup(entry["ansible_minimal_median"],
                                                    entry["rosdeploy_at_once_median"]), 2)
        # No tool at all (tool `floor`): what is left of the ratio when a tool costs nothing.
        entry["ratio_floor_minimal"] = _r(speedup(entry["ansible_minimal_median"], entry["floor_median"]), 2)
        entry["floor_steps"] = step_medians(floor)      # per robot: pull, stop, create, start, healthy
        entry["floor_inside"] = _r(median(m.wall_inside for m in floor if m.wall_inside is not None))
        entry["ratio_floor_ordered_minimal"] = _r(speedup(entry["ansible_minimal_median"],
                                                          entry["floor_ordered_median"]), 2)
        entry["floor_ordered_steps"] = step_medians(ordered)
        entry["floor_ordered_inside"] = _r(median(m.wall_inside for m in ordered if m.wall_inside is not None))
        entry["rosdeploy_at_once_steps"] = step_medians(at_once)
        entry["rosdeploy_steps"] = step_medians(ours)
        entry["rosdeploy_overhead"] = _r(overhead(ours))
        out[scenario] = entry
    return out


def fanout_section(raw: Mapping[str, Mapping[int, Sequence[Any]]]) -> dict[str, Any]:
    """Per command and N: wall seconds of each run, the median, and the median controller
    CPU (what stays on the operator's machine when every target has CPUs of its own)."""
    sizes = sorted({n for series in raw.values() for n in series})
    out: dict[str, Any] = {"sizes": sizes}
    for name, series in raw.items():
        out[name] = {str(n): {"runs": [round(t.seconds, 3) for t in series[n]],
                              "median": _r(median(t.seconds for t in series[n])),
                              "cpu_median": _r(median(t.cpu for t in series[n]))}
                     for n in sizes if n in series}
    return out


def goals(fleet: Mapping[str, Any], fanout: Mapping[str, Any]) -> list[Goal]:
    status = fanout.get("status", {})
    largest = max((int(n) for n in status), default=None)
    status_value = status[str(largest)]["median"] if largest else None
    return [
        Goal("noop", "no-op apply ≥ 10× faster than Ansible", fleet.get("noop", {}).get("speedup"), 10, True),
        Goal("upgrade", "upgrade ≤ ½ of Ansible's time (≥ 2×)", fleet.get("upgrade", {}).get("speedup"), 2, True),
        Goal("rollback", "emergency rollback ≤ ¼ of Ansible's redeploy (≥ 4×)",
             fleet.get("rollback", {}).get("speedup"), 4, True),
        Goal("status", f"status over {largest or 100} targets < 2 s (connections held, ssh.persist)",
             status_value, 2.0, False),
    ]


# Issue #19: a tool's time over the minimal playbook's (bench/ansible/minimal.yml), at most this.
ISSUE19_TARGETS = {"first_deploy": 0.4, "noop": 0.05, "upgrade": 0.35, "bad_release": 0.6, "rollback": 0.25}


def issue19(fleet: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per measured scenario: the target and the ratios over the minimal playbook of
    rosdeploy (canary first), rosdeploy at once and the floor (no tool). A floor above the
    target means no tool reaches it on this machine; below, a tool could."""
    out = []
    for scenario, entry in fleet.items():
        if scenario not in ISSUE19_TARGETS or entry.get("ansible_minimal_median") is None:
            continue
        out.append({"scenario": scenario, "target": ISSUE19_TARGETS[scenario],
                    "rosdeploy": entry.get("ratio_minimal"), "rosdeploy_at_once": entry.get("ratio_minimal_at_once"),
                    "floor": entry.get("ratio_floor_minimal"),
                    "floor_ordered": entry.get("ratio_floor_ordered_minimal")})
    return out


def issue19_lines(results: Mapping[str, Any]) -> list[str]:
    out = []
    for row in results.get("issue19") or issue19(results.get("fleet", {})):
        target = row["target"]
        shown = [f"{label} {_f(row[key])}" + ("" if row[key] is None else
                                               " (met)" if row[key] <= target else " (missed)")
                 for key, label in (("rosdeploy", "rosdeploy"), ("rosdeploy_at_once", "at once"),
                                    ("floor", "floor, no tool"), ("floor_ordered", "floor in depends_on order"))
                 if row.get(key) is not None]
        if not shown:
            continue
        line = f"{TITLES[row['scenario']]} ÷ minimal ≤ {target:.2f}: " + ", ".join(shown)
        if row["floor"] is not None:
            line += (" → the floor is above the target: no tool reaches it here" if row["floor"] > target
                     else " → the floor is below the target: a tool that ignores depends_on could reach it")
        if row.get("floor_ordered") is not None:
            line += ("; in depends_on order above it: no tool that keeps the order reaches it here"
                     if row["floor_ordered"] > target else
                     "; in depends_on order below it: a tool that keeps the order could reach it")
        out.append(line)
    return out


def machine() -> dict[str, Any]:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor() or "unknown")
    mem_kb = next(int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines()
                  if line.startswith("MemTotal"))
    return {"nproc": os.cpu_count(), "memory_gib": round(mem_kb / 1024 / 1024, 1), "cpu": cpu,
            "os": _os_name(), "python": platform.python_version()}


def _os_name() -> str:
    try:
        text = Path("/etc/os-release").read_text()
    except OSError:
        return platform.platform()
    match = re.search(r'^PRETTY_NAME="?([^"\n]+)"?', text, re.M)
    return match.group(1) if match else platform.platform()


def now_utc() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _r(value: float | None, digits: int = 3) -> float | None:
    return round(value, digits) if value is not None else None


# ------------------------------------------------------------------- table

def table_rows(results: Mapping[str, Any]) -> list[tuple[str, ...]]:
    rows: list[tuple[str, ...]] = []
    robots = results["config"]["robots"]
    for entry in results.get("fleet", {}).values():
        rows.append((f"{entry['title']} ({robots} robots)", _s(entry["rosdeploy_median"]),
                     _s(entry["ansible_median"]), _x(entry["speedup"]),
                     _s(entry.get("ansible_minimal_median")), _f(entry.get("ratio_minimal")),
                     _s(entry.get("rosdeploy_at_once_median")), _f(entry.get("ratio_minimal_at_once")),
                     _s(entry.get("floor_median")), _f(entry.get("ratio_floor_minimal")),
                     _s(entry.get("floor_ordered_median")), _f(entry.get("ratio_floor_ordered_minimal"))))
    fan = results.get("fanout", {})
    for n in fan.get("sizes", []):
        first, status = _get(fan, "status_first", n), _get(fan, "status", n)
        ours, theirs = _get(fan, "rosdeploy_noop", n), _get(fan, "ansible_noop", n)
        blank = ("",) * (len(HEADER) - 4)
        rows.append((f"fan-out: status, {n} targets, connecting", _s(first.get("median")), "—", "", *blank))
        rows.append((f"fan-out: status, {n} targets, connections held", _s(status.get("median")), "—", "", *blank))
        rows.append((f"fan-out: no-op apply, {n} targets", _s(ours.get("median")), _s(theirs.get("median")),
                     _x(speedup(ours.get("median"), theirs.get("median"))), *blank))
    return rows


def _get(fan: Mapping[str, Any], name: str, n: int) -> Mapping[str, Any]:
    return fan.get(name, {}).get(str(n), {})


def fanout_cpu_rows(results: Mapping[str, Any]) -> list[tuple[str, ...]]:
    fan = results.get("fanout", {})
    names = ("status_first", "status", "rosdeploy_noop", "ansible_noop")
    return [(str(n), *(_s(_get(fan, name, n).get("cpu_median")) for name in names)) for n in fan.get("sizes", [])]


CPU_HEADER = ("targets", "rosdeploy status (connecting)", "rosdeploy status (held)", "rosdeploy no-op",
              "Ansible no-op")


def _s(value: float | None) -> str:
    return f"{value:.2f} s" if value is not None else "—"


def _f(value: float | None) -> str:
    return f"{value:.2f}" if value is not None else "—"


def _x(value: float | None) -> str:
    return f"{value:.1f}×" if value is not None else "—"


def text_table(rows: Sequence[tuple[str, ...]], header: Sequence[str]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w)
                       for i, (c, w) in enumerate(zip(r, widths, strict=False)))
             for r in [header, *rows]]
    return "\n".join([lines[0], "-" * len(lines[0]), *lines[1:]])


def markdown_table(rows: Sequence[tuple[str, ...]], header: Sequence[str]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


HEADER = ("scenario", "rosdeploy (median)", "Ansible, equal work (median)", "speedup",
          "Ansible, minimal (median)", "rosdeploy ÷ minimal", "rosdeploy, all robots at once (median)",
          "at once ÷ minimal", "floor, no tool (median)", "floor ÷ minimal",
          "floor, depends_on order (median)", "ordered floor ÷ minimal")


def goal_lines(results: Mapping[str, Any]) -> list[str]:
    out = []
    for g in results["goals"]:
        verdict = {True: "MET", False: "MISSED", None: "not measured"}[g["met"]]
        value = "—" if g["value"] is None else (f"{g['value']:.2f} s" if g["name"] == "status"
                                                else f"{g['value']:.1f}×")
        out.append(f"{g['text']}: {value} → {verdict}")
    return out


def steps_table(results: Mapping[str, Any]) -> str:
    fleet = results.get("fleet", {})
    names: list[str] = []
    for entry in fleet.values():
        names += [n for n in entry["rosdeploy_steps"] if n not in names]
    rows = [(TITLES[s], _s(e["rosdeploy_overhead"]),
             *(f"{e['rosdeploy_steps'][n]:.2f}" if n in e["rosdeploy_steps"] else "" for n in names))
            for s, e in fleet.items()]
    return markdown_table(rows, ("scenario", "process + load + render", *names))


def floor_steps_table(results: Mapping[str, Any]) -> str:
    """The floors' phases, median seconds per robot from the robots' own clocks, and the
    slowest robot's total (the fleet wall time less the `docker exec` round trips)."""
    rows_in = [(f"{TITLES[s]}{label}", e[f"{key}_steps"], e.get(f"{key}_inside"), e.get(f"{key}_median"))
               for s, e in results.get("fleet", {}).items()
               for key, label in (("floor", ""), ("floor_ordered", ", depends_on order")) if e.get(f"{key}_steps")]
    names: list[str] = []
    for _, steps, _, _ in rows_in:
        names += [n for n in steps if n not in names]
    rows = [(title, *(f"{steps[n]:.2f}" if n in steps else "" for n in names), _s(inside), _s(wall))
            for title, steps, inside, wall in rows_in]
    return markdown_table(rows, ("scenario", *names, "slowest robot, inside", "fleet, wall"))


# ------------------------------------------------------------------ output

def carry_over(results: dict[str, Any], folder: Path) -> None:
    """A run that skipped a part (--skip-fleet, --fanout "") keeps that part from the newest
    saved run, labelled with that run's date and command, so the page stays whole."""
    saved = sorted(folder.glob("fleet-*.json"))
    if not saved:
        return
    previous = json.loads(saved[-1].read_text())
    for part in ("fleet", "fanout"):
        if not results.get(part) and previous.get(part):
            results[part] = previous[part]
            origin = (previous.get("carried_over") or {}).get(part) or {"date": previous["date"],
                                                                      "command": previous["command"]}
            results.setdefault("carried_over", {})[part] = origin


def save_json(results: Mapping[str, Any], folder: Path, suffix: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"fleet-{results['date'][:10]}{suffix}.json"
    path.write_text(json.dumps(results, indent=1, sort_keys=False) + "\n")
    return path


def docs_block(results: Mapping[str, Any], json_path: str) -> str:
    m = results["machine"]
    v = results["versions"]
    parts = [
        BEGIN,
        f"### Latest run: {results['date']}",
        "",
        f"- Command: `{results['command']}`",
        f"- Machine: {m['nproc']} cores ({m['cpu']}), {m['memory_gib']} GiB RAM, {m['os']}, Python {m['python']}",
        f"- Versions: rosdeploy {v['rosdeploy']}, ansible-core {v['ansible']}, Docker {v['docker']}, "
        f"Compose {v['compose']}",
        f"- Load average (1, 5, 15 min) at start {results['load_average']['start']}, "
        f"at end {results['load_average']['end']}",
        f"- Raw numbers: `{json_path}` (runs per scenario: {results['config']['runs']}; "
        f"Ansible fan-out runs per N: {results['config'].get('ansible_fanout_runs', 1)}; medians below)",
        *(f"- The {part} part is from the run of {origin['date']} (`{origin['command']}`)"
          for part, origin in (results.get("carried_over") or {}).items()),
        "",
        markdown_table(table_rows(results), HEADER),
        "",
        "Targets (each ratio compares the two tools within one run):",
        "",
        *(f"- {line}" for line in goal_lines(results)),
        "",
    ]
    if issue19_lines(results):
        parts += ["Issue #19 (a tool's time over the minimal playbook's; the floor is no tool at all):", "",
                  *(f"- {line}" for line in issue19_lines(results)), ""]
    if results.get("fanout"):
        parts += ["Fan-out, controller CPU (median user+sys seconds of the command and its children, and for "
                  "`status` the connection keeper's share: what stays on the operator's machine when every "
                  "target has its own CPUs):", "",
                  markdown_table(fanout_cpu_rows(results), CPU_HEADER), ""]
    if results.get("fleet"):
        parts += ["Where rosdeploy's time goes (median seconds per robot, from `--json` step timings):", "",
                  steps_table(results), ""]
    if any(e.get("floor_steps") or e.get("floor_ordered_steps") for e in results.get("fleet", {}).values()):
        parts += ["Where the floor's time goes (median seconds per robot, from the robots' clocks):", "",
                  floor_steps_table(results), ""]
    if results.get("fanout_error"):
        parts += [f"The fan-out part stopped early: {results['fanout_error'].splitlines()[0]}", ""]
    if results.get("discarded_rounds"):
        parts += [f"{len(results['discarded_rounds'])} round(s) failed their result check and were run again "
                  "(see `discarded_rounds` in the JSON).", ""]
    parts.append(END)
    return "\n".join(parts)


def write_docs(path: Path, block: str) -> None:
    text = path.read_text() if path.exists() else "# Benchmarks\n\n"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block + rest.split(END, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(text)
