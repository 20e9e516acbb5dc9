"""What a user's own templates render, read back the way the robot reads it (checks.py's rules call these).

The host files (the udev rules, logrotate.conf and logrotate.cron) are installed as root outside the
release (hostchanges-root.sh), and cron, logrotate and udev run what they say as root. rosdeploy's own
templates write a fixed shape; an override may only narrow it, never run a program or reach another
path. So each reader here allows exactly what the built-in template can render, and names anything
else with its line: that is a root shell on every robot, the same as `privileged` in compose.yml.

`compose_schema_findings` holds a compose template's output to the Compose schema fleet.py holds the
fleet's `compose:` keys to (schemas/compose_spec.json: Compose v1 1.29.2's, which v2 reads too).

Pure functions of text: no printing, no files read (but the schema, once).
"""
from __future__ import annotations

import posixpath
import re
import shlex
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

from rosdeploy import rotation, schema_quick
from rosdeploy.errors import shown
from rosdeploy.model import FleetSpec, Host

UDEV_FILE = "99-rosdeploy.rules"
ROOT = "as root on every robot"


@dataclass(frozen=True)
class Finding:
    """A line of a rendered file (1-based) and what is wrong there, said in full."""

    line: int
    message: str


@dataclass(frozen=True)
class Rotation:
    """What the built-in logrotate templates render for one robot (render.Renderer._context)."""

    project: str
    logs_dir: str       # <deploy_root>/<project>/logs, absolute (logrotate does not read `~`)

    @property
    def conf(self) -> str:
        return f"{rotation.CONF_DIR}/{rotation.installed_name(self.project)}"

    @property
    def cron(self) -> str:
        return f"{rotation.CRON_DIR}/{rotation.installed_name(self.project)}"

    @property
    def state(self) -> str:
        return rotation.state_file(self.project)


def rotation_for(spec: FleetSpec, host: Host) -> Rotation:
    """What render writes into the built-in logrotate.conf for this robot (render.Renderer._deploy_root:
    the deploy root made absolute with rosdeploy_home, else /root for root or no user, else /home/<user>)."""
    root = str(host.vars.get("rosdeploy_deploy_root") or spec.deploy_root).rstrip("/") or "/"
    if root == "~" or root.startswith("~/"):
        home = host.vars.get("rosdeploy_home") or spec.vars.get("rosdeploy_home") or (
            "/root" if host.user in (None, "root") else f"/home/{host.user}")
        root = str(home).rstrip("/") + root[1:]
    return Rotation(spec.project, f"{root}/{spec.project}/logs")


def _fix(installed: str) -> str:
    return (f"the file is installed as {installed}; remove it from the template (rosdeploy's host changes "
            "are only udev names for declared devices and the ROS log rotation: give other root jobs to your "
            "provisioning). `allow_privileged` does not waive it: that trusts one container, not the robot")


# ------------------------------------------------------------------ logrotate.cron

_CRON_NICKNAMES = frozenset({"@reboot", "@yearly", "@annually", "@monthly", "@weekly", "@daily", "@midnight",
                             "@hourly"})
_CRON_VAR = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(.*?)\s*$")
# The built-in file's variables, as it sets them: another SHELL runs the job with another program,
# another PATH finds another `logrotate`, and cron hands any other variable (LD_PRELOAD, BASH_ENV) to the job.
_CRON_VARS = {"SHELL": ("/bin/sh",), "PATH": ("/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",)}
_CRON_HARMLESS = frozenset({"MAILTO", "CRON_TZ"})
_LOGROTATE = ("logrotate", "/usr/sbin/logrotate", "/sbin/logrotate", "/usr/bin/logrotate")


def cron_findings(text: str, expected: Rotation) -> list[Finding]:
    """Each line of a rendered logrotate.cron that is not the built-in's: a variable other than
    SHELL/PATH as the built-in sets them (MAILTO, CRON_TZ are fine), or a job other than
    `root logrotate -s <state> <conf>` on any schedule."""
    where = f"{rotation.CRON_FILE} line"
    out = []
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        var = _CRON_VAR.match(line)
        if var and not line.lstrip().startswith("@") and not line.lstrip()[:1].isdigit() and \
                not line.lstrip().startswith("*"):
            name, value = var.group(1), var.group(2).strip("'\"")
            if name in _CRON_HARMLESS or value in _CRON_VARS.get(name, ()):
                continue
            out.append(Finding(number, f"{where} {number} sets {name}={shown(value)}, which every job of the file "
                                       f"runs with {ROOT}: only SHELL=/bin/sh and the built-in PATH are rosdeploy's; "
                                       + _fix(expected.cron)))
            continue
        command = _cron_command(stripped)
        if command is None:
            out.append(Finding(number, f"{where} {number} ({shown(stripped[:80])}) is not a cron job line "
                                       "(five time fields or an @nickname, then the user and the command): "
                                       + _fix(expected.cron)))
        elif command != ("root", "logrotate", "-s", expected.state, expected.conf):
            out.append(Finding(number, f"{where} {number} runs {shown(' '.join(command[1:])[:120])} as user "
                                       f"{shown(command[0])} on every robot, from cron: the only job rosdeploy "
                                       f"installs is `root logrotate -s {expected.state} {expected.conf}`; "
                                       + _fix(expected.cron)))
    return out


def _cron_command(line: str) -> tuple[str, ...] | None:
    """(user, command words...) of a system crontab job line, logrotate's path made plain; None: no job line.
    cron hands the command to the shell, and `%` makes the rest of it stdin: any such character is kept in
    a word, so the comparison with the one allowed command fails."""
    words = line.split()
    fields = 1 if words and words[0] in _CRON_NICKNAMES else 5
    if len(words) < fields + 2 or (fields == 5 and not all(re.fullmatch(r"[0-9A-Za-z*/,-]+", w) for w in words[:5])):
        return None
    user, command = words[fields], words[fields + 1:]
    if command[0] in _LOGROTATE:
        command = ["logrotate", *command[1:]]
    return (user, *command)


# ------------------------------------------------------------------ 99-rosdeploy.rules

# KEY, KEY{attr}; an operator; a double-quoted value (`e"…"` takes C escapes in newer udev).
_UDEV_PAIR = re.compile(r'\s*([A-Za-z_]+)(?:\{([^}]*)\})?\s*(==|!=|\+=|-=|:=|=)\s*(e?"(?:[^"\\]|\\.)*")\s*(,|$)')
# Keys that only match a device: they cannot run, write or change anything.
_UDEV_MATCH = frozenset({"ACTION", "SUBSYSTEM", "SUBSYSTEMS", "KERNEL", "KERNELS", "DRIVER", "DRIVERS", "ATTR",
                         "ATTRS", "ENV", "TAG", "TAGS", "DEVPATH", "NAME", "SYMLINK", "TEST", "CONST"})
# What the built-in template assigns (templates/udev.rules.j2): a name under /dev, the group and the mode.
_UDEV_ASSIGN = frozenset({"SYMLINK", "GROUP", "MODE"})
# Every assignment is to a device the inventory declared by its USB ids, as the built-in's are.
_UDEV_IDS = ("idVendor", "idProduct")


def udev_findings(text: str, installed: str = "/etc/udev/rules.d/99-rosdeploy-<project>.rules") -> list[Finding]:
    """Each rule of a rendered 99-rosdeploy.rules that does more than the built-in's: a key that runs a
    program (RUN, PROGRAM, IMPORT{program}), loads or writes something (IMPORT{file}, ATTR{…}=, ENV{…}=
    which can start units, OWNER, NAME, OPTIONS, GOTO/LABEL), or assigns to a device not matched by its
    ATTRS{idVendor} and ATTRS{idProduct} (KERNEL=="sda", MODE="0666": the disk, world-writable)."""
    return [finding for number, rule in _udev_rules(text) for finding in _udev_rule(number, rule, installed)]


def _udev_rules(text: str) -> Iterator[tuple[int, str]]:
    """(first line, the rule's text) with backslash-newline continuations joined; comments skipped."""
    start, parts = 0, list[str]()
    for number, line in enumerate(text.splitlines(), 1):
        if not parts:
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            start = number
        if line.endswith("\\"):
            parts.append(line[:-1])
            continue
        parts.append(line)
        yield start, " ".join(parts)
        parts = []
    if parts:
        yield start, " ".join(parts)


def _udev_rule(number: int, rule: str, installed: str) -> Iterator[Finding]:
    where = f"{UDEV_FILE} line {number}"
    pairs, position = [], 0
    while position < len(rule):
        m = _UDEV_PAIR.match(rule, position)
        if m is None or m.end() == position:
            yield Finding(number, f"{where}: cannot read {shown(rule[position:position + 80])} as udev keys "
                                  "(KEY==\"value\", comma-separated): " + _fix(installed))
            return
        pairs.append((m.group(1), m.group(2), m.group(3), m.group(4)))
        position = m.end()
    matched = {attr for key, attr, op, _ in pairs if key == "ATTRS" and op == "=="}
    assigns = False
    for key, attr, op, value in pairs:
        shown_key = f"{key}{{{attr}}}" if attr is not None else key
        if op in ("==", "!=") and key in _UDEV_MATCH:
            continue
        if key in _UDEV_ASSIGN and op in ("=", "+=", ":="):
            assigns = True
            continue
        runs = key in ("RUN", "PROGRAM") or (key == "IMPORT" and attr in ("program", None))
        what = f"runs {shown(value.removeprefix('e')[1:-1])}" if runs else "acts on the robot"
        yield Finding(number, f"{where}: `{shown_key}{op}` {what} {ROOT} (udev does it at every event of a "
                              "matching device); the built-in rules only match a device and set SYMLINK, GROUP "
                              "and MODE: " + _fix(installed))
    missing = [attr for attr in _UDEV_IDS if attr not in matched]
    if assigns and missing:
        yield Finding(number, f"{where}: sets SYMLINK/GROUP/MODE on devices not matched by "
                              f"{' and '.join(f'ATTRS{{{a}}}==' for a in missing)}: it can reach a disk or any "
                              f"device ({ROOT}); declare the device in the robot's `udev` inventory entry (vendor, "
                              "product), as the built-in template renders it")


# ------------------------------------------------------------------ logrotate.conf

_SCRIPTS = frozenset({"postrotate", "prerotate", "firstaction", "lastaction", "preremove"})
# Directives that neither run a program nor reach a path of their own: rotation timing, counts, sizes,
# compression with logrotate's default gzip, names of the rotated files.
_LOGROTATE_PLAIN = frozenset({
    "su", "size", "minsize", "maxsize", "rotate", "maxage", "start", "hourly", "daily", "weekly", "monthly",
    "yearly", "copytruncate", "nocopytruncate", "copy", "nocopy", "compress", "nocompress", "delaycompress",
    "nodelaycompress", "compressext", "compressoptions", "missingok", "nomissingok", "notifempty", "ifempty",
    "dateext", "nodateext", "dateformat", "dateyesterday", "datehourago", "extension", "addextension",
    "nocreate", "nocreateolddir", "noolddir", "nomail", "nosharedscripts", "sharedscripts", "shred", "noshred",
    "shredcycles", "tabooext", "taboopat", "noallowhardlink", "ignoreduplicates", "renamecopy", "norenamecopy",
    "create", "createolddir", "olddir",
})
_LOGROTATE_RUNS = {"mail": "mails the rotated log with the `mail` program", "mailfirst": "mails a log",
                   "maillast": "mails a log", "compresscmd": "compresses with this program",
                   "uncompresscmd": "uncompresses with this program",
                   "include": "reads another config, which can hold anything",
                   "allowhardlink": ("rotates a hard link: a container can link /etc/shadow into the world-writable "
                                     "log folder, and root truncates it")}


def logrotate_findings(text: str, expected: Rotation) -> list[Finding]:
    """Each line of a rendered logrotate.conf that does more than the built-in's: a script
    (postrotate, prerotate, firstaction, lastaction, preremove … endscript), a directive that runs a
    program or reads another file (mail, compresscmd, include), allowhardlink, a log path outside
    <deploy_root>/<project>/logs, an `olddir` outside it, or a `create`/`createolddir` mode that lets anyone write."""
    out: list[Finding] = []
    in_script = False
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if in_script:
            in_script = stripped != "endscript"
            continue
        if not stripped or stripped.startswith("#"):
            continue
        words = _words(stripped)
        if words is None:
            out.append(Finding(number, f"{rotation.CONF_FILE} line {number}: unbalanced quotes: "
                                       + _fix(expected.conf)))
            continue
        words = [w for w in words if w not in ("{", "}")]
        if not words or stripped.startswith("}"):
            continue
        if stripped[0].isalpha():
            directive = words[0].lower()
            in_script = directive in _SCRIPTS
            out += _directive(number, directive, words[1:], expected)
        else:
            out += _paths(number, words, expected)
    return out


def _words(line: str) -> list[str] | None:
    """The line's words as logrotate splits them (quotes group a path with blanks); `{` may end one."""
    try:
        return shlex.split(line.replace("{", " { ").replace("}", " } "), comments=True)
    except ValueError:
        return None


def _directive(number: int, name: str, args: list[str], expected: Rotation) -> list[Finding]:
    where = f"{rotation.CONF_FILE} line {number}"
    if name in _SCRIPTS:
        return [Finding(number, f"{where}: `{name}` starts a shell script that logrotate runs {ROOT} at every "
                                "rotation: " + _fix(expected.conf))]
    if name in _LOGROTATE_RUNS:
        return [Finding(number, f"{where}: `{' '.join([name, *args])[:120]}` {_LOGROTATE_RUNS[name]}, {ROOT}: "
                                + _fix(expected.conf))]
    if name not in _LOGROTATE_PLAIN:
        return [Finding(number, f"{where}: `{name}` is not a logrotate directive rosdeploy knows to be harmless "
                                f"(logrotate runs {ROOT}): " + _fix(expected.conf))]
    if name == "olddir" and args and not _under(args[0], expected.logs_dir):
        return [Finding(number, f"{where}: `olddir {shown(args[0])}` moves the rotated logs outside "
                                f"{expected.logs_dir}, {ROOT}: keep them there (or drop olddir)")]
    if name in ("create", "createolddir") and args and re.fullmatch(r"[0-7]{3,4}", args[0]) and \
            int(args[0], 8) & 0o002:
        return [Finding(number, f"{where}: `{name} {args[0]}` makes the files anyone can write, created {ROOT}: "
                                "use a mode without write for others (0640), or drop it (the built-in copies and "
                                "truncates)")]
    return []


def _paths(number: int, paths: list[str], expected: Rotation) -> list[Finding]:
    return [Finding(number, f"{rotation.CONF_FILE} line {number}: rotates {shown(path)}, outside the project's log "
                            f"folder {expected.logs_dir}: logrotate rewrites, truncates and deletes it {ROOT} "
                            f"(with `create` it may hand it to anyone); " + _fix(expected.conf))
            for path in paths if not _under(path, expected.logs_dir)]


def _under(path: str, folder: str) -> bool:
    """Whether the path (a glob) stays inside folder: absolute, no `..`, below it (not it)."""
    if not path.startswith("/") or ".." in path.split("/"):
        return False
    normal = posixpath.normpath(path)
    return normal.startswith(posixpath.normpath(folder).rstrip("/") + "/")


# ------------------------------------------------------------------ compose.yml against the schema

# Compose v1 and v2 both cast a string where the schema wants a boolean or a number, before
# validating (v1 compose/config/interpolation.py, v2 compose-go's interpolation casts): these words only.
_TRUE_FALSE = frozenset({"y", "yes", "true", "on", "n", "no", "false", "off"})
_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


# Keys Compose v2 (the compose-spec) reads that the vendored v1 schema does not: v2 accepts them
# (`docker compose config -q`), v1 1.29.2 refuses the file. Left out on purpose, so still refused:
# `use_api_socket` (the Docker socket), `provider` (runs a program on the robot at `up`),
# `post_start`/`pre_stop` (can run privileged), `uts`, `models`. `include` is compose-invalid's to judge.
V2_SERVICE_KEYS = frozenset({"annotations", "attach", "cgroup", "develop", "gpus", "label_file", "pull_refresh_after"})
V2_TOP_KEYS = frozenset({"name", "include", "models"})


@dataclass(frozen=True)
class SchemaFinding:
    path: tuple[Any, ...]       # the key path in compose.yml
    message: str
    v2_accepts: bool = False    # only Compose v1 refuses it (a key the compose-spec added since 1.29.2)


def compose_schema_findings(compose: Mapping[str, Any]) -> list[SchemaFinding]:
    """Each place the parsed, interpolated compose.yml breaks the Compose schema the fleet's `compose:`
    keys are held to (an unknown key such as `Privileged`, a wrong type such as `privileged: "1"`), as
    Compose validates it: after interpolation, with the strings it casts to booleans and numbers taken.
    Only a user template's output needs it: the built-in one is written from checked data."""
    from rosdeploy.fleet import _compose_schema_data, _compose_validator
    schema = _compose_schema_data()
    if schema_quick.verdict(schema, compose) is True:
        return []     # valid for certain, without jsonschema (schema_quick.py says why)
    out = []
    for err in sorted(_compose_validator().iter_errors(dict(compose)), key=lambda e: list(map(str, e.path))):
        if err.validator == "additionalProperties" and isinstance(err.instance, dict):
            out += _unknown_keys(err)
        elif not _cast_by_compose(err):
            out.append(SchemaFinding(tuple(err.path), _message(err)))
    return out


def _unknown_keys(err: Any) -> list[SchemaFinding]:
    """One finding per key the schema does not know, at its own path, with a did-you-mean (`Privileged`)."""
    from rosdeploy.suggest import did_you_mean
    known = [str(k) for k in err.schema.get("properties", {})]
    path = tuple(err.path)
    v2 = V2_TOP_KEYS if not path else V2_SERVICE_KEYS if len(path) == 2 and path[0] == "services" else frozenset()
    out = []
    for key in err.instance:
        if key in known or str(key).startswith("x-"):
            continue
        hint = did_you_mean(str(key), known)
        if key in v2:
            out.append(SchemaFinding(path + (key,), f"{shown(key)} is a key Compose v1 1.29.2 does not know", True))
        else:
            out.append(SchemaFinding(path + (key,), f"{shown(key)} is not a key Compose knows there (keys are "
                                                    f"case-sensitive){'; ' + hint if hint else ''}"))
    return out


def _cast_by_compose(err: Any) -> bool:
    """A string where a boolean or a number goes, which Compose casts rather than refuses (also as the
    only error of one branch of a oneOf/anyOf: a long-form volume's `read_only: "false"`)."""
    if err.validator in ("oneOf", "anyOf"):
        branches: dict[Any, list[Any]] = {}
        for sub in err.context or ():
            branches.setdefault(sub.relative_schema_path[0] if sub.relative_schema_path else None, []).append(sub)
        return any(all(_cast_by_compose(sub) for sub in subs) for subs in branches.values())
    if err.validator != "type" or not isinstance(err.instance, str):
        return False
    kinds = err.validator_value if isinstance(err.validator_value, list) else [err.validator_value]
    text = err.instance.strip()
    return ("boolean" in kinds and text.lower() in _TRUE_FALSE) or \
        (bool({"number", "integer"} & set(kinds)) and bool(_NUMBER.fullmatch(text)))


def _message(err: Any) -> str:
    if err.validator == "type" and isinstance(err.instance, str) and "boolean" in str(err.validator_value):
        return f"{shown(err.instance)} is no boolean (Compose takes true/false, yes/no, y/n or on/off)"
    return err.message[:200]
