"""ROS log rotation that runs on the robot between deploys, with no controller around.

The release carries two files (rendered from templates/logrotate*.j2):

- `logrotate.conf`: size-based rotation of `<deploy_root>/<project>/logs/*/*.log` with
  `copytruncate` (the nodes keep their files open and keep writing; no signal reaches a ROS
  node's log handler), installed as /etc/logrotate.d/rosdeploy-<project>;
- `logrotate.cron`: the schedule, installed as /etc/cron.d/rosdeploy-<project>. It runs
  `logrotate -s <its own state file>` as root every `logging.rotate_every`.

Both are host changes (hostchanges.py): installed as root after the upload, taken from a
release directory, so a rollback installs the kept release's schedule again. Why root even
for a non-root SSH user: containers write their log files as their own uid, often root, and
copytruncate needs write access to the file. Why cron rather than a systemd timer: one
file, no daemon-reload, and it works the same on a robot without systemd (a container, the
sim); Debian's cron picks up a changed /etc/cron.d within a minute.
"""
from __future__ import annotations

DEFAULT_EVERY = 300.0    # 5 min: one stat per log file; a node can overshoot the cap by what it writes in one period
CONF_DIR = "/etc/logrotate.d"
CRON_DIR = "/etc/cron.d"
STATE_DIR = "/var/lib/logrotate"
CONF_FILE = "logrotate.conf"     # in the release
CRON_FILE = "logrotate.cron"     # in the release

# Periods cron keeps evenly: minutes that divide an hour, hours that divide a day.
_MINUTES = (1, 2, 3, 4, 5, 6, 10, 12, 15, 20, 30)
_HOURS = (1, 2, 3, 4, 6, 8, 12, 24)
PERIODS = ", ".join([f"{m}m" for m in _MINUTES] + [f"{h}h" for h in _HOURS])


def installed_name(project: str) -> str:
    """The name of both installed files (cron.d ignores names with dots: none here)."""
    return f"rosdeploy-{project}"


def state_file(project: str) -> str:
    return f"{STATE_DIR}/{installed_name(project)}.status"


def cron_schedule(seconds: float | None) -> str | None:
    """The cron time fields for a period, or None when cron cannot keep it evenly."""
    if seconds is None or seconds <= 0 or seconds % 60:
        return None
    minutes = int(seconds // 60)
    if minutes in _MINUTES:
        return "* * * * *" if minutes == 1 else f"*/{minutes} * * * *"
    hours, rest = divmod(minutes, 60)
    if rest or hours not in _HOURS:
        return None
    return "0 0 * * *" if hours == 24 else f"0 */{hours} * * *"


def context(project: str, every: float | None) -> dict[str, str]:
    """What templates/logrotate.cron.j2 reads: an empty schedule renders a file without jobs."""
    name = installed_name(project)
    return {"rotate_schedule": cron_schedule(every) or "", "rotate_conf": f"{CONF_DIR}/{name}",
            "rotate_state": state_file(project)}
