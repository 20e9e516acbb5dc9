"""Maintenance windows: images are pulled at once, the switch happens only inside the window.

    window: {days: [mon, tue], start: "01:00", duration: 3h, tz: Europe/Berlin}

`days` (default: every day) names the day each window *starts*; a window may run past
midnight. `start` is wall-clock time in `tz` (an IANA name, read with the standard
library's zoneinfo; default UTC); `duration` is elapsed time, so a window that spans a
DST change lasts exactly `duration`. A start time that a spring-forward skips (02:30 on
the last Sunday of March in Berlin) opens at the same instant as the hour before it
would plus the skipped offset (zoneinfo's fold=0 reading: 03:30 local), and one that a
fall-back repeats opens at its first occurrence.

No cron form: a days/start/duration triple says everything a weekly window needs, and
croniter would add a dependency whose `duration` we would still have to carry beside it.

Set in the fleet file for every robot, or as an inventory var `window:` per group or
host (which replaces the fleet file's; `window: false` switches at any time).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, time as dtime, timedelta, timezone
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from rosdeploy.errors import shown
from rosdeploy.ready import known_keys
from rosdeploy.suggest import did_you_mean

DAYS = ("mon", "tue", "wed", "thu", "fri", "sat", "sun")
_KEYS = ("days", "start", "duration", "tz")
_START_RE = re.compile(r"([01]?\d|2[0-3]):([0-5]\d)(?::([0-5]\d))?")   # HH:MM, or HH:MM:SS


@dataclass(frozen=True)
class Window:
    days: frozenset[int]        # 0 = Monday; every day when empty
    start: dtime                # local wall-clock time in tz
    duration: timedelta
    tz: str = "UTC"

    def describe(self) -> str:
        days = ",".join(DAYS[d] for d in sorted(self.days)) if self.days else "daily"
        start = self.start.isoformat("seconds" if self.start.second else "minutes")
        return f"{days} {start} for {_hours(self.duration)} ({self.tz})"


def _hours(d: timedelta) -> str:
    minutes = int(d.total_seconds() // 60)
    return f"{minutes // 60}h{minutes % 60:02d}m" if minutes % 60 else f"{minutes // 60}h"


# Files of the zoneinfo folder that are not IANA zone names: `localtime` is the controller's own
# zone (not the robots'), `Factory` has no offset of any place, `posixrules` is a default rule set;
# posix/ and right/ are copies of the zones (right/ counts leap seconds, off from wall clocks).
_NOT_ZONES = frozenset({"localtime", "Factory", "posixrules"})


def _not_a_zone_name(name: str) -> bool:
    return name in _NOT_ZONES or name.startswith(("posix/", "right/"))


def convert(r: Any, kp: tuple, value: Any) -> Window | bool | None:
    """A fleet-file converter (fleet.Reader protocol): `window:` -> Window, False (none),
    or None after reporting the problems with r.error(keypath, message)."""
    from rosdeploy.fleet import parse_duration

    before = len(r.problems)
    shape = 'a mapping like {days: [mon, tue], start: "01:00", duration: 3h, tz: Europe/Berlin}'
    if value is False or not known_keys(r, kp, value, _KEYS, shape):
        return False if value is False else None
    days = _days(r, kp + ("days",), value.get("days", []))
    start = value.get("start")
    match = _START_RE.fullmatch(start) if isinstance(start, str) else None
    if match is None:
        r.error(kp + ("start",), f'required: the local time the window opens, quoted, e.g. "01:00"; got {shown(start)}')
    # Each refusal is also kept here: the reader shows no second message under a value it
    # already refused (control characters), so its problem count need not grow.
    duration: float | None = None
    try:
        duration = parse_duration(value.get("duration"))
        if not 0 < duration <= 7 * 86400:
            raise ValueError
    except ValueError:
        duration = None
        r.error(kp + ("duration",), f"required: how long it stays open, e.g. 3h or 90m (at most 7 days); "
                                    f"got {shown(value.get('duration'))}")
    tz = value.get("tz", "UTC")
    try:
        if _not_a_zone_name(str(tz)):
            raise ValueError(tz)
        ZoneInfo(str(tz))
    except (ZoneInfoNotFoundError, ValueError):
        r.error(kp + ("tz",), f"{shown(tz)} is not a time zone name: use an IANA name like Europe/Berlin or UTC")
        tz = None
    if len(r.problems) > before or match is None or duration is None or tz is None:
        return None
    return Window(frozenset(days), dtime(int(match.group(1)), int(match.group(2)), int(match.group(3) or 0)),
                  timedelta(seconds=duration), str(tz))


def _days(r: Any, kp: tuple, value: Any) -> list[int]:
    if not isinstance(value, list):
        r.error(kp, "must be a list of days, e.g. [mon, tue, sat]")
        return []
    out = []
    for i, day in enumerate(value):
        name = str(day).lower()[:3]
        if name not in DAYS or str(day).lower() not in (name, _full(name)):
            r.error(kp + (i,), f"{shown(day)} is not a day: use {', '.join(DAYS)} {did_you_mean(day, DAYS)}".strip())
        else:
            out.append(DAYS.index(name))
    return out


def _full(abbrev: str) -> str:
    return {"mon": "monday", "tue": "tuesday", "wed": "wednesday", "thu": "thursday", "fri": "friday",
            "sat": "saturday", "sun": "sunday"}[abbrev]


def openings(window: Window, now: datetime) -> tuple[datetime, datetime]:
    """The window occurrence that contains `now`, else the next one: (opens, closes), in UTC.
    `now` must be aware."""
    zone = ZoneInfo(window.tz)
    local_day = now.astimezone(zone).date()
    # From the day before (a window that opened yesterday may still be open) up to a week on.
    for offset in range(-1, 9):
        day = local_day + timedelta(days=offset)
        if window.days and day.weekday() not in window.days:
            continue
        opens = datetime.combine(day, window.start, tzinfo=zone).astimezone(timezone.utc)
        closes = opens + window.duration
        if now < closes:
            return opens, closes
    raise AssertionError("a weekly window always has an occurrence within 8 days")   # days is never empty-set-of-none


def inside(window: Window, now: datetime) -> bool:
    opens, _ = openings(window, now)
    return opens <= now


def next_open(window: Window, now: datetime) -> datetime:
    """When the switch may happen: `now` inside a window, else the next opening."""
    opens, _ = openings(window, now)
    return max(opens, now)
