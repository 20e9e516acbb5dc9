"""(FleetSpec, Host) -> RenderedRelease: every file one robot receives.

Pure and deterministic: the only I/O is reading templates (once, when the
Renderer is built), nothing depends on time or dict order, so the same inputs
give byte-identical files and the same digest, and a release id means content.

Python decides *what* goes into the files (resolved devices, groups, peers,
secrets, validation); the Jinja2 templates in templates/ decide only the
layout, so a user who overrides a template gets the same checked context.
Every inventory or fleet value reaches a file through a quoting filter
(yaml_str, compose_str, xml, env_value, udev_value): no value can break the
syntax of the file it lands in.
"""
from __future__ import annotations

import dataclasses
import functools
import ipaddress
import json
import re
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import jinja2
import yaml

from rosdeploy import restarts, rotation
from rosdeploy.checks import host_problem
from rosdeploy.compose_env import parse_env
from rosdeploy.compose_data import compose_data
from rosdeploy.errors import InputError, Problem, RenderError, shown
from rosdeploy.files import FILES_DIR, MAX_TEMPLATE_BYTES, FileRenderer, reads_as_other, represent_text
from rosdeploy.fleet import MANAGED_COMPOSE, RESERVED_ENV, size_bytes
from rosdeploy.inventory.draft import strings
from rosdeploy.inventory.templating import (HostVars, not_quoted, raw_vars, secret_read, secret_reads,
                                            shown_unless_secret, unless_secret)
from rosdeploy.model import FleetSpec, Host, RenderedFile, RenderedRelease, Service, UdevDevice, secret_key
from rosdeploy.sandbox import (ContainedLoader, Layered, Sandbox, ShippedSandbox, describe, render_value,
                               shipped_cache,
                               value_template)
from rosdeploy.yamlsrc import Doc, Unsafe, read_bytes

# rosdeploy/templates is a link to the repo's top-level templates/ in a checkout, and a real
# directory in an installed wheel (setuptools copies what the link points at).
TEMPLATE_DIR = Path(__file__).parent / "templates"

COMPOSE_FILE = "compose.yml"
ENV_FILE = ".env"
RELEASE_METADATA = frozenset({"manifest.json", "images.txt"})     # added by the upload (deploy._tarball)
UDEV_FILE = "99-rosdeploy.rules"
LOGROTATE_FILE = rotation.CONF_FILE
ROTATION_FILE = rotation.CRON_FILE

# rmw key in the fleet file -> (RMW_IMPLEMENTATION, DDS profile file, env vars pointing at it).
# Fast DDS 2.x (Humble, Jazzy) reads FASTRTPS_DEFAULT_PROFILES_FILE; 3.x reads
# FASTDDS_DEFAULT_PROFILES_FILE and warns on the old name: set both, one image may be either.
RMW = {
    "fastdds": ("rmw_fastrtps_cpp", "fastdds.xml",
                {"FASTDDS_DEFAULT_PROFILES_FILE": "/fastdds.xml", "FASTRTPS_DEFAULT_PROFILES_FILE": "/fastdds.xml"}),
    "cyclonedds": ("rmw_cyclonedds_cpp", "cyclonedds.xml", {"CYCLONEDDS_URI": "file:///cyclonedds.xml"}),
}

# Keys the built-in compose template writes for a service (fleet.MANAGED_COMPOSE is the one list);
# `extra` may not repeat them (a duplicate mapping key is a YAML error in Compose v2, a silent
# override in v1).
RENDERED_SERVICE_KEYS = frozenset(MANAGED_COMPOSE)

GPU_ENV = {"NVIDIA_VISIBLE_DEVICES": "all", "NVIDIA_DRIVER_CAPABILITIES": "compute,utility,video"}
GPU_SHM_BYTES = 1 << 30          # the practices doc: ~1 GB of /dev/shm for GPU services
FASTDDS_PARTICIPANT_SLOTS = 4    # Fast DDS's maxInitialPeersRange: participant ids 0..3 per peer

_SERVICE_NAME = re.compile(r"[a-zA-Z0-9][a-zA-Z0-9_.-]*\Z")
_ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_HEX4 = re.compile(r"[0-9a-fA-F]{4}\Z")
_SPACE = re.compile(r"\s")   # str.isspace, character by character (both are Py_UNICODE_ISSPACE)
MIN_LEAK_CHECK = 4               # shorter vault values would match innocent text
# Characters YAML may not carry raw inside a quoted scalar (non-printable, or read as line breaks).
_YAML_UNSAFE = re.compile("[\x7f-\x9f\u2028\u2029\ufeff\ud800-\udfff]")
_LINE_BREAKS = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


# Fast DDS keeps durations as int32 seconds (Duration_t) and counts as 32-bit; logrotate reads its
# counts as int: past 2**31 - 1 a tunable is a typo, and would overflow the reader on the robot.
MAX_TUNABLE = 2**31 - 1
# SO_RCVBUF is an int: CycloneDDS cannot ask for a socket buffer of 2 GiB or more.
MAX_SOCKET_BUFFER = 2**31 - 1
# CycloneDDS's memsize units, matched exactly (its unittab_memsize; kB is 1024 there too): it
# refuses `10k`, `10M` or `10KB`, and the robot's DDS would not start
_SOCKET_BUFFER_RE = re.compile(r"([0-9]+(?:\.[0-9]+)?)(?: *(B|KiB|kB|MiB|MB|GiB|GB))?")
_LOGROTATE_SIZE_RE = re.compile(r"([0-9]+)([kMG]?)")


def _int_between(low: int, high: int = MAX_TUNABLE) -> Any:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and low <= v <= high


def _size_within(pattern: re.Pattern, low: int, high: int) -> Any:
    """A size `pattern` reads as (number, unit of B, k, M or G, binary as CycloneDDS and logrotate
    read them) between low and high bytes."""
    def check(value: Any) -> bool:
        try:
            match = None if isinstance(value, bool) else pattern.fullmatch(str(value))
        except ValueError:      # str() of an int past 4,300 digits
            return False
        if not match:
            return False
        scale = 1024 ** "BkMG".index((match.group(2) or "B")[0].replace("K", "k"))
        return low <= float(match.group(1)) * scale <= high
    return check


# Inventory (or fleet `vars:`) variables the templates read: name -> (default, check, what it must be).
TUNABLES: dict[str, tuple[Any, Any, str]] = {
    "dds_lease_duration": (10, _int_between(1), f"whole seconds from 1 to {MAX_TUNABLE}"),
    # below dds_lease_duration, too (Renderer._tunables): Fast DDS refuses an announcement period
    # as long as the lease, and the peers would drop the participant between two announcements
    "dds_lease_announcement": (3, _int_between(1), f"whole seconds from 1 to {MAX_TUNABLE}"),
    # Fast DDS sends 5 announcements 100 ms apart, then one per lease announcement (3 s),
    # and does not answer a new participant's. One that starts later than the announcements
    # last (a later container, the gate's ROS probe, often 3-4 s after the driver) waits up
    # to 3 s to discover its peers: seen in 5 of 12 gate probes with 15 x 200 ms. 50 x 200 ms
    # covers health.topics_within's default 10 s, for a one-off burst of small packets.
    "dds_initial_announcements": (50, _int_between(1), f"a number of announcements from 1 to {MAX_TUNABLE}"),
    "dds_initial_announcement_period_ms": (200, _int_between(1), f"whole milliseconds from 1 to {MAX_TUNABLE}"),
    "dds_socket_buffer": ("10MB", _size_within(_SOCKET_BUFFER_RE, 1, MAX_SOCKET_BUFFER),
                          "a size like 10MB or 8MiB, below 2GiB (a socket buffer size is an int)"),
    "logrotate_size": ("50M", _size_within(_LOGROTATE_SIZE_RE, 0, 1 << 40),
                       "a size of at most 1024G, like 50M (0 rotates any file that is not empty)"),
    "logrotate_keep": (5, _int_between(0), f"a number of rotated files from 0 to {MAX_TUNABLE}"),
}


class _Rejected(ValueError):
    """A value no quoting can carry safely into the file (raised inside filters)."""


class _OnlyInEnv(Sequence[tuple[str, str]]):
    """The `secrets` of a template that renders anything but .env: how many there are, never their
    values. A value read here would reach a file that is not secret, in any form (`value|reverse`)."""

    def __init__(self, secrets: Sequence[tuple[str, str]]) -> None:
        self._count = len(secrets)

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, index: Any) -> Any:
        raise _Rejected("`secrets` holds the vault values that go to .env, and only env.j2 may read them: "
                        "for the names, read the service's `secrets` (as compose.yml.j2 does)")


class _EnvSecrets(Sequence[tuple[str, str]]):
    """env.j2's `secrets`: the (name, value) pairs, noting which names were read. An error raised
    after reading one is not quoted: masking the output finds a secret's exact text only, not
    `value|reverse|join` in a "No filter named .." or a TemplateNotFound."""

    def __init__(self, secrets: Sequence[tuple[str, str]]) -> None:
        self._secrets = tuple(secrets)
        self._read: dict[str, None] = {}     # env names, in the order read (private: the sandbox refuses `_`)

    def __len__(self) -> int:
        return len(self._secrets)

    def __getitem__(self, index: Any) -> Any:
        item = self._secrets[index]
        for name, _ in (item if isinstance(index, slice) else (item,)):
            self._read.setdefault(name, None)
        return item


# ------------------------------------------------------------------- filters

_PLAIN = re.compile(r"[A-Za-z0-9 _./:@%+,=${}()*!?#&~^\[\]-]*")


def _dumped(data: Any) -> str:
    """`compose:` pass-through keys as YAML. PyYAML writes U+2028, U+2029 and U+0085 raw inside a
    quoted scalar, where YAML reads them as line breaks and folds them into a space (two
    extra_hosts entries became one): with one of them in the data, every non-ASCII character is
    escaped instead."""
    text = yaml.dump(data, Dumper=_Dumper, sort_keys=True, default_flow_style=False, allow_unicode=True,
                     width=1 << 16)
    if any(c in text for c in "\u2028\u2029\x85"):
        text = yaml.dump(data, Dumper=_Dumper, sort_keys=True, default_flow_style=False, width=1 << 16)
    return text


def yaml_str(value: Any) -> str:
    """A double-quoted YAML scalar that parses back to str(value), whatever it holds."""
    text = str(value)
    if _PLAIN.fullmatch(text):   # nothing to escape in a double-quoted scalar (the common case)
        return f'"{text}"'
    text = json.dumps(text, ensure_ascii=False)   # JSON strings are YAML double-quoted scalars
    return _YAML_UNSAFE.sub(lambda m: f"\\u{ord(m.group()):04x}", text)


_BARE_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]*")


def yaml_key(value: Any) -> str:
    """A mapping key: bare when YAML 1.1 and 1.2 both read it as this plain string, else quoted."""
    text = str(value)
    if _BARE_KEY.fullmatch(text) and not reads_as_other(text):
        return text
    return yaml_str(text)


def compose_str(value: Any) -> str:
    """yaml_str for compose.yml, where `$` starts an interpolation: fleet values are literal."""
    return yaml_str(str(value).replace("$", "$$"))


def compose_list(values: Iterable[Any]) -> str:
    return "[" + ", ".join(compose_str(v) for v in values) + "]"


def env_ref(name: str) -> str:
    """A compose reference to a .env variable that fails loudly when the variable is missing."""
    return yaml_str(f"${{{name}:?{name} must be set in .env}}")


def xml(value: Any) -> str:
    """Escape for XML text and attribute values."""
    text = str(value)
    if _LINE_BREAKS.search(text.replace("\t", "")) or _YAML_UNSAFE.search(text):
        raise _Rejected(f"{shown(text)} contains a control character and cannot go into an XML file")
    # What xml.sax.saxutils.escape(text, {'"': ..., "'": ...}) does; that module imports
    # urllib.request (http.client, ssl, email): 12 ms of every command's start (issue 18).
    return (text.replace("&", "&amp;").replace(">", "&gt;").replace("<", "&lt;")
            .replace('"', "&quot;").replace("'", "&apos;"))


def env_value(value: Any) -> str:
    """Quote for .env so Compose v2 (compose-go) and v1 (python-dotenv) read back the same string.

    Single quotes: v2 neither interpolates `$` nor reads escapes there; v1 turns `\\\\` and `\\'`
    into one character, and expands `${NAME}` even inside single quotes (python-dotenv's
    interpolation, which `$$` or a backslash does not escape). No quoting is read the same by
    both, so those sequences are refused rather than read two ways.
    """
    text = str(value)
    if re.fullmatch(r"[A-Za-z0-9_./:@%+,=-]*", text):
        return text
    if "'" in text or _LINE_BREAKS.search(text.replace("\t", "")) or "\\\\" in text or text.endswith("\\") \
            or "${" in text:
        raise _Rejected("a .env value may not contain a newline, a control character, a single quote, `${`, "
                        "a double backslash or a trailing backslash (Compose v1 and v2 would read it differently: "
                        "v1 expands `${NAME}` even in quotes)")
    return f"'{text}'"


def udev_value(value: Any) -> str:
    text = str(value)
    if '"' in text or "\\" in text or _LINE_BREAKS.search(text):
        raise _Rejected(f"{shown(text)} cannot go into a udev rule (no quotes, backslashes or control characters)")
    return text


def logrotate_path(value: Any) -> str:
    text = str(value)
    if '"' in text or "{" in text or "}" in text or _LINE_BREAKS.search(text):
        raise _Rejected(f"{shown(text)} cannot go into a logrotate config (no quotes, braces or control characters)")
    return f'"{text}"' if any(c.isspace() for c in text) else text


def comment(value: Any) -> str:
    """One line of text safe inside a `#` or XML comment."""
    return _LINE_BREAKS.sub("?", str(value)).replace("--", "- -")


FILTERS = {
    "yaml_str": yaml_str, "yaml_key": yaml_key, "compose_str": compose_str, "compose_list": compose_list,
    "env_ref": env_ref,
    "xml": xml, "env_value": env_value, "udev_value": udev_value, "logrotate_path": logrotate_path,
    "comment": comment,
}


# ------------------------------------------------------------------ context

@dataclass(frozen=True)
class HealthView:
    test: tuple[str, ...]
    interval: str
    timeout: str
    retries: int
    start_period: str


@dataclass(frozen=True)
class ServiceView:
    """One compose service as the templates see it: everything resolved for this robot."""

    name: str
    image: str                              # full ref, as in RenderedRelease.images
    command: tuple[str, ...] | None
    environment: tuple[tuple[str, str], ...]   # sorted, non-secret, literal values
    secrets: tuple[str, ...]                # env names whose values live in .env
    restart: str
    mem_limit: str | None
    cpus: float | None
    healthcheck: HealthView | None
    depends_on: tuple[str, ...]
    devices: tuple[str, ...]                # "/dev/x:/dev/x"
    group_add: tuple[str, ...]
    user: str | None
    privileged: bool
    profiles: tuple[str, ...]
    gpu: bool                               # service wants a GPU AND the robot has one
    shm_size: str
    log_dir: str                            # relative to the release dir
    volumes: tuple[str, ...]                # the user's bind mounts, after rosdeploy's own
    labels: tuple[tuple[str, str], ...]
    extra_yaml: str                         # `extra`, YAML-dumped and indented for the service block
    extra: Mapping[str, Any]                # `extra` as data, `$` escaped unless compose_interpolate
    mounts: tuple[str, ...] = ()            # per-robot files (fleet `files:`), "source:target:ro"


@dataclass(frozen=True)
class UdevView:
    """One udev rule: a host.udev entry, checked, with its group filled in from the subsystem."""

    subsystem: str
    vendor: str
    product: str
    serial: str | None
    symlink: str
    group: str | None
    mode: str


@dataclass(frozen=True)
class _Static:
    """The host-independent part of a service, computed once per Renderer."""

    service: Service
    image: str
    environment: Mapping[str, str]          # plain values
    templated: Mapping[str, jinja2.Template]  # values with {{ }} rendered per robot
    secrets: tuple[tuple[str, str], ...]    # (env name, host var), sorted
    healthcheck: HealthView | None
    labels: tuple[tuple[str, str], ...]
    extra_yaml: str
    extra: Mapping[str, Any]


class _Dumper(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):  # type: ignore[misc]
    """libyaml's emitter where PyYAML has it; never anchors and aliases (compose v1 chokes on some).
    Strings as files.represent_text writes them: Compose v2 reads YAML 1.2, where a bare `1e3` is a
    number (it refuses `hostname: 1e3`), though PyYAML writes it bare as YAML 1.1's string."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


_Dumper.add_representer(str, represent_text)
_Dumper.add_multi_representer(str, represent_text)


def _taken_names(builtin: Mapping[str, str]) -> dict[str, str]:
    """Release names an extra template may not render to, and why: a second file of the same name
    would replace rosdeploy's (or be replaced by it), and a file where the release has a folder
    cannot be written at all."""
    taken = {name: f"is written by rosdeploy into every release, from {template}: to replace it, name this "
                   f"template {template}" for name, template in builtin.items()}
    taken |= {name: "is written by rosdeploy into every release (version, digest, image ids): rename this template"
              for name in RELEASE_METADATA}
    taken |= {name: "is a folder of every release (stored and per-robot files): rename this template"
              for name in (restarts.STORE, FILES_DIR)}
    return taken


def _output_name_problem(name: str) -> str | None:
    """Why an extra template's output name (its file name without .j2) cannot be a release file,
    or None. `.j2` and `..j2` name the release folder or its parent; a blank or a leading `-`
    is a name the robot's shell scripts and compose would split or read as an option."""
    if name in ("", ".", ".."):
        return (f"renders to {shown(name)}, which is no file name (it would be the release folder or its "
                "parent): name the template NAME.j2, e.g. notes.txt.j2")
    odd = next((c for c in name if "\udc80" <= c <= "\udcff"), None)    # os.listdir's stand-in for a bad byte
    if odd is not None:
        return (f"renders to {shown(name)}, whose name is not UTF-8 (byte 0x{ord(odd) - 0xdc00:02x}): a release file's "
                "name is written into its manifest and read by the robot's tools as UTF-8; rename the template, "
                "e.g. notes.txt.j2")
    if name.startswith("-") or any(c.isspace() or not c.isprintable() for c in name):
        return (f"renders to {shown(name)}: a file name with a blank, a control character or a leading `-` "
                "is split or read as an option by the robot's shell scripts and compose; rename the template, "
                "e.g. notes.txt.j2")
    return None


def _escape_dollars(value: Any) -> Any:
    """`compose:` values are literal unless the service opts in: `$` -> `$$` in every string value."""
    if isinstance(value, dict):
        return {k: _escape_dollars(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_escape_dollars(v) for v in value]
    return value.replace("$", "$$") if isinstance(value, str) else value


def _size_bytes(text: str) -> int:
    try:
        return size_bytes(text)
    except ValueError:
        return 0


def _host_problem(host: Host, key: str, message: str) -> Problem:
    """At the var `key` where its value was set, else where the robot is declared."""
    return host_problem(host, key, f"robot {shown(host.name)}: {message}")


def _with_mounts(svc: ServiceView, mounts: tuple[str, ...]) -> ServiceView:
    """The service with the robot's own files mounted (a copy only when it has some: most have none)."""
    return replace(svc, mounts=mounts) if mounts else svc


def _device_group(path: str, logical: str, udev: UdevDevice | None) -> str | None:
    """The group a container user needs for a device node: dialout for serial, video for cameras."""
    subsystem = ""
    if udev is not None:
        if udev.group:
            return udev.group
        subsystem = udev.subsystem
    base = path.rsplit("/", 1)[-1]
    hints = f"{path} {logical}".lower()
    if subsystem == "tty" or base.startswith("tty") or "/serial/" in path or "serial" in logical.lower():
        return "dialout"
    if subsystem == "video4linux" or base.startswith("video") or "/v4l/" in path or "camera" in hints:
        return "video"
    return None


# ------------------------------------------------------------ template folder

class _NotATemplate(jinja2.TemplateError):
    """A template folder's entry that cannot be read as a template: at its own path."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = str(path), reason


class _TemplateFolder(ContainedLoader):
    """A user's template folder, each file read once as yamlsrc reads configuration: a regular file
    (non-blocking open, so a FIFO cannot hang it) of at most MAX_TEMPLATE_BYTES, inside the folder.
    A name that exists but is no such file (a FIFO, a folder, a link to a missing file) is an
    error, not TemplateNotFound: the ChoiceLoader would quietly use the built-in template."""

    def get_source(self, environment: jinja2.Environment, template: str) -> tuple[str, str, Any]:
        pieces = jinja2.loaders.split_template_path(template)    # TemplateNotFound on `..`
        root = Path(self.searchpath[0])
        path = root.joinpath(*pieces)
        if not (path.is_symlink() or path.exists()):
            raise jinja2.TemplateNotFound(template)
        try:
            inside = path.resolve().is_relative_to(root.resolve())
        except (OSError, RuntimeError) as exc:     # a link loop (RuntimeError before Python 3.13)
            raise _NotATemplate(path, f"cannot be opened ({exc}): fix the link") from None
        if not inside:
            raise jinja2.sandbox.SecurityError(f"template {template} is a link to a file outside the template folder: "
                                               "copy the file into the folder instead")
        if path.is_symlink() and not path.exists():
            raise _NotATemplate(path, "a link to a missing file: fix the link, or remove it")
        if path.is_dir():      # read_bytes would say only "Is a directory"
            raise _NotATemplate(path, "not a regular file but a folder: a template is a text file")
        try:
            data = read_bytes(str(path), MAX_TEMPLATE_BYTES, "a template (a text file)")
        except InputError as exc:
            raise _NotATemplate(path, exc.problems[0].message) from None
        try:
            return data.decode("utf-8"), str(path), lambda: True
        except UnicodeDecodeError as exc:
            raise jinja2.TemplateSyntaxError(f"byte 0x{data[exc.start]:02x} is not UTF-8: save the template as UTF-8",
                                             data[:exc.start].count(b"\n") + 1, template, str(path)) from None


# ----------------------------------------------------------------- renderer

def _builtin_environment() -> jinja2.Environment:
    """rosdeploy's own templates, where no override replaces them: code shipped with rosdeploy,
    rendered in Jinja's sandbox without rosdeploy's bounds on top (sandbox.ShippedSandbox).
    Every value a user writes (fleet values, `files:`, an override folder) renders in the
    bounded sandbox (Renderer._environment)."""
    env = ShippedSandbox(plain_types=_VIEWS, hidden_of=_CONTROLLER_FIELDS,
                         loader=jinja2.FileSystemLoader(str(TEMPLATE_DIR)),
                         trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True, auto_reload=False,
                         bytecode_cache=shipped_cache())
    env.filters.update(FILTERS)
    return env


_VIEWS = (ServiceView, HealthView, UdevView, Host, FleetSpec)
# The controller's side, which templates do not see: its paths (as given on its command line, or
# with its environment expanded) and where it read the robot's declaration. Not in the repr
# either (`{{ spec }}`), so the same inputs render the same release from any folder or machine.
_CONTROLLER_FIELDS = {FleetSpec: frozenset({"path", "inventory", "templates", "known_hosts", "ssh_config"}),
                      Host: frozenset({"key_file", "key_file_var", "source"})}
_BUILTIN = _builtin_environment()


class Renderer:
    """Compiles the templates of one FleetSpec once; `render(host)` is then cheap and pure."""

    def __init__(self, spec: FleetSpec, secret_key: bytes | None = None) -> None:
        """`secret_key`: the key of secret content's digests (model.secret_key), when the caller
        derives one from the vault password; else each robot's is derived from its vault values."""
        self.spec = spec
        self.secret_key = secret_key
        if spec.rmw not in RMW:
            raise RenderError([self._problem(("ros", "rmw"),
                                             f"unknown rmw {shown(spec.rmw)} (use {' or '.join(RMW)})")])
        if spec.network_mode not in ("host", "bridge"):
            raise RenderError([self._problem(("ros", "network_mode"),
                                             f"unknown network_mode {shown(spec.network_mode)} (use host or bridge)")])
        self.rmw_implementation, self.dds_file, self.dds_env = RMW[spec.rmw]
        self.override = self._override_dir()
        self.env = self._environment()
        outputs = {COMPOSE_FILE: "compose.yml.j2", ENV_FILE: "env.j2", self.dds_file: f"{self.dds_file}.j2",
                   LOGROTATE_FILE: "logrotate.conf.j2", UDEV_FILE: "udev.rules.j2",
                   ROTATION_FILE: "logrotate.cron.j2"}
        outputs.update(self._user_only_templates(outputs))
        self.templates = {out: self._compile(name) for out, name in sorted(outputs.items())}
        compose_file = self.templates[COMPOSE_FILE].filename or ""
        self.builtin_compose = Path(compose_file).resolve().parent == TEMPLATE_DIR.resolve()
        self.statics = tuple(self._static(s) for s in spec.services)
        self.secret_vars: dict[str, str] = {}      # .env name -> the var it reads (the first service's)
        for st in self.statics:
            for name, var in st.secrets:
                self.secret_vars.setdefault(name, var)
        self.images = tuple(sorted({s.image for s in self.statics}))
        self.image_vars = self._image_vars()
        try:
            self.robot_files = FileRenderer(spec, self.env)
        except jinja2.TemplateSyntaxError as exc:
            raise RenderError([self._problem(("files",), f"template syntax error in a path: {exc.message}")]) from exc

    # --- setup --------------------------------------------------------------

    def _problem(self, keypath: tuple[Any, ...], message: str) -> Problem:
        """A problem in the fleet file, at the line of the key when the loader recorded it."""
        return Doc(self.spec.path, None, self.spec.lines).problem(keypath, message)

    def _override_dir(self) -> Path | None:
        if not self.spec.templates:
            return None
        path = Path(self.spec.templates)
        if not path.is_absolute():
            path = Path(self.spec.path).resolve().parent / path
        if not path.is_dir():
            raise RenderError([self._problem(("templates",), f"template directory {path} does not exist")])
        return path

    def _environment(self) -> jinja2.Environment:
        """Sandboxed (rosdeploy.sandbox): fleet values and template folders are configuration, not code."""
        loaders: list[jinja2.BaseLoader] = [_TemplateFolder(str(self.override))] if self.override else []
        loaders.append(jinja2.FileSystemLoader(str(TEMPLATE_DIR)))
        env = Sandbox(plain_types=_VIEWS, hidden_of=_CONTROLLER_FIELDS,
                      loader=jinja2.ChoiceLoader(loaders),
                      trim_blocks=True, lstrip_blocks=True,
                      keep_trailing_newline=True, auto_reload=False)
        env.add_filters(FILTERS)
        return env

    def _overridden(self, name: str) -> bool:
        if self.override is None:
            return False
        path = self.override / name
        return path.is_symlink() or path.exists()    # a bad link is the sandbox loader's to refuse

    def _user_only_templates(self, builtin: Mapping[str, str]) -> dict[str, str]:
        """Extra `NAME.j2` files in the override dir render to NAME (`_*.j2` are partials)."""
        if self.override is None:
            return {}
        known = set(builtin.values()) | {"fastdds.xml.j2", "cyclonedds.xml.j2"}
        # every entry, not only files: a FIFO or a folder named NAME.j2 is refused when compiled (_TemplateFolder)
        extra = {p.name[:-3]: p.name for p in sorted(self.override.glob("*.j2"))
                 if p.name not in known and not p.name.startswith("_")}
        problems = [Problem(str(self.override / extra[name]), None, "", f"{name} {why}")
                    for name, why in sorted(_taken_names(builtin).items()) if name in extra]
        problems += [Problem(str(self.override / template), None, "", why)
                     for name, template in sorted(extra.items()) for why in [_output_name_problem(name)] if why]
        if problems:
            raise RenderError(problems)
        return extra

    def _compile(self, name: str) -> jinja2.Template:
        if not self._overridden(name):
            return _BUILTIN.get_template(name)
        try:
            return self.env.get_template(name)
        except jinja2.TemplateSyntaxError as exc:
            raise RenderError([Problem(exc.filename or name, exc.lineno, "",
                                       f"template syntax error: {exc.message}")]) from exc
        except jinja2.TemplateNotFound as exc:
            raise RenderError([self._problem(("templates",), f"template {exc.name} not found")]) from exc
        except _NotATemplate as exc:     # a FIFO, a folder, a dangling link, over MAX_TEMPLATE_BYTES
            raise RenderError([Problem(exc.path, None, "", exc.reason)]) from exc
        except jinja2.TemplateError as exc:   # e.g. a link out of the template folder (_TemplateFolder)
            raise RenderError([self._problem(("templates",), exc.message or str(exc))]) from exc

    def _static(self, svc: Service) -> _Static:
        spec, where = self.spec, ("services", svc.name)
        problems: list[Problem] = []
        if not _SERVICE_NAME.match(svc.name):
            problems.append(self._problem(where, "a service name may hold only letters, digits, '_', '.', '-'"))
        plain: dict[str, str] = {}
        templated: dict[str, jinja2.Template] = {}
        for key, value in svc.environment.items():
            if not key or "=" in key or _LINE_BREAKS.search(key):
                problems.append(self._problem(where + ("environment",), f"invalid variable name {shown(key)}"))
            elif not isinstance(value, Unsafe) and ("{{" in str(value) or "{%" in str(value)):
                if len(str(value)) > MAX_TEMPLATE_BYTES:     # compiled whole, before any bound of the sandbox
                    problems.append(self._problem(where + ("environment", key), (
                        f"a templated value of over {MAX_TEMPLATE_BYTES:,} characters: write the value itself, or "
                        "put the logic in the inventory")))
                    continue
                try:
                    templated[key] = value_template(self.env, str(value))
                except jinja2.TemplateSyntaxError as exc:
                    problems.append(self._problem(where + ("environment", key),
                                                  f"template syntax error: {exc.message}"))
            else:
                plain[key] = str(value)
        for name in svc.secret_env:
            if not _ENV_NAME.match(name):
                problems.append(self._problem(where + ("secrets",), f"invalid variable name {shown(name)}"))
        clash = sorted(RENDERED_SERVICE_KEYS & set(svc.extra))
        if clash:
            problems.append(self._problem(where + ("compose",),
                                    f"{', '.join(clash)} {'is' if len(clash) == 1 else 'are'} rendered by rosdeploy; "
                                    "set the fleet-file key instead of `compose:`"))
        if problems:
            raise RenderError(problems)
        hc = svc.healthcheck
        extra, extra_data = "", dict(svc.extra) if svc.compose_interpolate else _escape_dollars(dict(svc.extra))
        if svc.extra:
            extra = "".join(f"    {line}\n" for line in _dumped(extra_data).split("\n") if line)
        return _Static(
            service=svc, image=spec.image_ref(svc), environment=plain, templated=templated,
            secrets=tuple(sorted(svc.secret_env.items())),
            healthcheck=(HealthView(tuple(hc.test), hc.interval, hc.timeout, hc.retries, hc.start_period)
                         if hc else None),
            # No release version here: a label that changes with every release would make compose
            # recreate every container. The per-service hash is added per robot (restarts.py).
            labels=(("io.rosdeploy.project", spec.project), ("io.rosdeploy.service", svc.name)),
            extra_yaml=extra, extra=extra_data)

    def _image_vars(self) -> tuple[tuple[str, str], ...]:
        owners: dict[str, str] = {}
        for st in self.statics:
            var = image_var(st.service.name)
            if var in owners:
                raise RenderError([self._problem(("services", st.service.name),
                                           f"services {shown(owners[var])} and {shown(st.service.name)} both map to "
                                           f"{var} in .env; rename one")])
            owners[var] = st.service.name
        return tuple(sorted((image_var(st.service.name), st.image) for st in self.statics))

    # --- per robot ----------------------------------------------------------

    def render(self, host: Host) -> RenderedRelease:
        problems: list[Problem] = []
        context = self._context(host, problems)
        key = self.secret_key or secret_key(frozenset(host.secret_values))
        own = self.robot_files.render(host, context["vars"], problems, key)
        if problems:
            raise RenderError(problems)
        # compose.yml last: it names the other files by content (restarts.stored) and carries
        # each service's hash, so unchanged services keep their containers across releases.
        rendered = [self._file(out, tpl, context, host) for out, tpl in self.templates.items() if out != COMPOSE_FILE]
        dds = next(f for f in rendered if f.name == self.dds_file)
        store = [restarts.stored(dds)]
        context["dds_source"] = restarts.mount_source(store[0])
        context["services"] = [restarts.with_hash(_with_mounts(sv, own.mounts.get(sv.name, ())), context, key)
                               for sv in context["services"]]
        rendered.append(self._file(COMPOSE_FILE, self.templates[COMPOSE_FILE], context, host))
        files = sorted(rendered + store + list(own.files), key=lambda f: f.name)
        self._check_leaks(host, files)
        return RenderedRelease(host=host.name, project=self.spec.project, version=self.spec.version,
                               files=tuple(files), images=self.images,
                               secret_values=frozenset(value for _, value in context["secrets"]) | own.secret_values,
                               compose_data=self._compose_data(context, files), secret_key=key)

    def _compose_data(self, context: Mapping[str, Any], files: list[RenderedFile]) -> Any:
        """(as written, as compose reads it with the .env) for the built-in compose template."""
        if not self.builtin_compose:
            return None
        env = parse_env(next(f.content for f in files if f.name == ENV_FILE))
        return compose_data(context), compose_data(context, env)

    def _context(self, host: Host, problems: list[Problem]) -> dict[str, Any]:
        """What the templates see; every problem found on the way goes to `problems`."""
        spec, variables = self.spec, Layered(host.vars, self.spec.vars)
        return {
            "spec": spec, "host": host, "vars": variables, "project": spec.project, "version": spec.version,
            "network_mode": spec.network_mode, "rmw": spec.rmw, "rmw_implementation": self.rmw_implementation,
            "dds_file": self.dds_file, "dds_env": sorted(self.dds_env.items()),
            "shm_size": spec.shm_size, "log_max_size": spec.log_max_size, "log_max_file": spec.log_max_file,
            "ros_domain_id": host.ros_domain_id, "fastdds_ports": self._fastdds_ports(host.ros_domain_id),
            "services": [self._service(st, host, variables, problems) for st in self.statics],
            "secrets": self._secrets(host, problems), "image_vars": self.image_vars, "udev": self._udev(host, problems),
            "dds_source": f"./{self.dds_file}", **self._read_vars(host, variables, problems),
            **rotation.context(spec.project, spec.log_rotate_every),
        }

    def _read_vars(self, host: Host, variables: Mapping[str, Any], problems: list[Problem]) -> dict[str, Any]:
        """The inventory vars rosdeploy itself writes into the (not secret) DDS profile, compose.yml
        and logrotate config: refused if they come from a vault."""
        with secret_reads() as secret:
            peers = self._peers(host, variables, problems)
            out = {"peers": peers, "ipv6_peers": tuple(p for p in peers if _is_ipv6(p)),
                   "logs_glob": f"{self._deploy_root(host, variables, problems)}/{self.spec.project}/logs/*/*.log",
                   **self._tunables(host, variables, problems)}
        problems.extend(_host_problem(host, var, f"{secret_read(var, source)} is written to "
                                                 "non-secret files (DDS profile, compose.yml, logrotate): set it "
                                                 "in a plain vars file") for var, source in sorted(secret.items()))
        return out

    def _service(self, st: _Static, host: Host, variables: Mapping[str, Any], problems: list[Problem]) -> ServiceView:
        svc = st.service
        gpu = svc.gpu and host.gpu
        env = dict(GPU_ENV) if gpu else {}
        env.update(st.environment)
        derived = set()
        for key, template in st.templated.items():
            where = ("services", svc.name, "environment", key)
            with secret_reads() as secret:
                env[key] = self._render_value(template, host, variables, where, problems)
            if "\0" in env[key]:     # execve's strings end at a NUL: no environment can hold one
                problems.append(self._problem(where, f"robot {shown(host.name)}: this value comes out with a NUL "
                                                     "byte, which no environment variable can hold: fix the "
                                                     "inventory value or the expression"))
            if secret:
                derived.add(key)
                problems.append(self._problem(where, f"robot {shown(host.name)}: this value reads "
                                                     f"{secret_read(*min(secret.items()))} into compose.yml, which "
                                                     f"is not secret; {_TO_SECRETS.format(key=key)}"))
        self._check_env_leaks(host, svc.name, {k: v for k, v in env.items() if k not in derived}, problems)
        udev_by_path = {f"/dev/{u.symlink}": u for u in host.udev}
        devices, groups = [], set()
        for logical in svc.devices:
            path = host.devices.get(logical)
            if path is None:
                problems.append(_host_problem(host, f"devices.{logical}",
                                              f"service {shown(svc.name)} needs device {shown(logical)}, which the "
                                              "robot's devices map does not define"))
                continue
            if not path.startswith("/") or ":" in path or _SPACE.search(path):
                problems.append(_host_problem(host, f"devices.{logical}",
                                              f"device path {shown(path)} must be absolute, without ':' or spaces"))
                continue
            devices.append(f"{path}:{path}")
            group = _device_group(path, logical, udev_by_path.get(path))
            if group:
                groups.add(group)
        shm = self.spec.shm_size
        if gpu and _size_bytes(shm) < GPU_SHM_BYTES:
            shm = "1g"
        return ServiceView(
            name=svc.name, image=st.image, command=tuple(svc.command) if svc.command is not None else None,
            environment=tuple(sorted(env.items())), secrets=tuple(name for name, _ in st.secrets),
            restart=svc.restart, mem_limit=svc.memory, cpus=svc.cpus, healthcheck=st.healthcheck,
            depends_on=tuple(sorted(svc.depends_on)), devices=tuple(devices), group_add=tuple(sorted(groups)),
            user=svc.user, privileged=svc.privileged, profiles=tuple(svc.profiles), gpu=gpu,
            shm_size=shm, log_dir=f"../../logs/{svc.name}", volumes=svc.volumes, labels=st.labels,
            extra_yaml=st.extra_yaml, extra=st.extra)

    def _render_value(self, template: jinja2.Template, host: Host, variables: Mapping[str, Any],
                      key: tuple[str, ...], problems: list[Problem]) -> str:
        try:
            return render_value(template, {"vars": variables, "host": host, "inventory_hostname": host.name},
                                variables)
        except jinja2.TemplateError as exc:
            problems.append(self._problem(key, f"robot {shown(host.name)}: {unless_secret(exc.message or '')}"))
            return ""

    def _check_env_leaks(self, host: Host, service: str, env: Mapping[str, str], problems: list[Problem]) -> None:
        """A vault value copied into an `environment:` value: reported at the fleet key that copies it."""
        secrets = _searched(host)
        for key in sorted(k for k, value in env.items() if any(s in value for s in secrets)):
            problems.append(self._problem(("services", service, "environment", key), (
                f"robot {shown(host.name)}: this value copies a vault secret into compose.yml, which is not secret; "
                f"{_TO_SECRETS.format(key=key)}")))

    def _secrets(self, host: Host, problems: list[Problem]) -> list[tuple[str, str]]:
        """(env name, value) for every secret env of every service, sorted; values validated for .env."""
        chosen: dict[str, tuple[str, str]] = {}   # env name -> (host var, service)
        for st in self.statics:
            for name, var in st.secrets:
                if name in chosen and chosen[name][0] != var:
                    problems.append(self._problem(("services", st.service.name, "secrets", name),
                                            f"{name} is read from {chosen[name][0]} by service "
                                            f"{shown(chosen[name][1])} and from {var} here: one .env cannot hold both"))
                chosen.setdefault(name, (var, st.service.name))
        reserved = {"COMPOSE_PROJECT_NAME", "ROSDEPLOY_PROJECT", "ROSDEPLOY_VERSION", *RESERVED_ENV} | \
            {image_var(st.service.name) for st in self.statics}
        out = []
        for name, (var, service) in sorted(chosen.items()):
            key = ("services", service, "secrets", name)
            if name in reserved:
                problems.append(self._problem(key, f"{name} is a variable rosdeploy writes to .env itself"))
            elif name.startswith(("COMPOSE_", "DOCKER_")):
                # compose reads its own settings from .env: COMPOSE_FILE, COMPOSE_PROFILES, DOCKER_HOST…
                problems.append(self._problem(key, f"{name} in .env is a setting of docker compose itself "
                                                   "(which file, profiles, engine), not the service's: "
                                                   "choose another name"))
            elif var not in host.vars:
                problems.append(_host_problem(host, var, f"service {shown(service)} reads secret {name} from var "
                                                         f"{shown(var)}, which is not defined for this robot"))
            else:
                value = host.vars[var]
                why = _secret_problem(name, value)
                if why:
                    problems.append(_host_problem(host, var, f"secret {name}: {why}"))
                    continue
                out.append((name, str(value)))
        return out

    def _peers(self, host: Host, variables: Mapping[str, Any], problems: list[Problem]) -> tuple[str, ...]:
        """Unicast DDS peers: every service of this release on a bridge network, then `dds_peers`."""
        with secret_reads() as read:
            extra = _defined(variables.get("dds_peers", []))
        if read:    # refused by _read_vars; any message here would quote what was computed from it
            return ()
        if isinstance(extra, str):
            extra = [extra]
        if not isinstance(extra, (list, tuple)) or not all(isinstance(p, str) and p for p in extra):
            problems.append(self._var_problem(host, "dds_peers", "dds_peers must be a list of robot addresses"))
            return ()
        bad = [p for p in extra if not _is_peer_address(p)]
        if bad:
            problems.append(self._var_problem(host, "dds_peers", (
                f"{', '.join(repr(p) for p in bad[:5])} {'is' if len(bad) == 1 else 'are'} not an IP address or "
                "host name: list the other robots' addresses, e.g. [10.0.0.12, amr-2.local]")))
            return ()
        own = [s.name for s in self.spec.services] if self.spec.network_mode == "bridge" else []
        seen: dict[str, None] = {}
        for peer in [*own, *extra]:
            seen.setdefault(peer, None)
        ipv6 = [p for p in seen if _is_ipv6(p)]
        # a host name resolves to what the transport asks for; a service name on a Docker bridge
        # (`own`) to the bridge's IPv4 address
        ipv4 = [p for p in seen if _is_ipv4(p) or p in own]
        if self.spec.rmw == "cyclonedds" and ipv6 and ipv4:
            # CycloneDDS runs one transport per domain, udp (IPv4) or udp6: it cannot reach both kinds
            problems.append(self._var_problem(host, "dds_peers", (
                f"{', '.join(repr(p) for p in ipv6[:5])}: CycloneDDS talks either IPv4 or IPv6 in a domain, and "
                f"{', '.join(repr(p) for p in ipv4[:5])} are IPv4: list every peer by its IPv4 address, or every "
                "one by its IPv6 address (or host name) on host networking")))
            return ()
        return tuple(seen)

    @staticmethod
    def _udev(host: Host, problems: list[Problem]) -> tuple[UdevView, ...]:
        out = []
        for u in sorted(host.udev, key=lambda u: u.symlink):
            key = f"udev.{u.symlink}"
            bad = [f"{what} {shown(value)}" for what, value, ok in (
                ("vendor id", u.vendor, _HEX4.match(u.vendor)), ("product id", u.product, _HEX4.match(u.product)),
                ("symlink", u.symlink, re.fullmatch(r"[A-Za-z0-9_.+-]+(/[A-Za-z0-9_.+-]+)*", u.symlink)),
                ("mode", u.mode, re.fullmatch(r"0?[0-7]{3}", u.mode))) if not ok]
            if bad:
                problems.append(_host_problem(host, key, "invalid " + ", ".join(bad)))
                continue
            group = u.group or {"tty": "dialout", "video4linux": "video"}.get(u.subsystem)
            out.append(UdevView(u.subsystem, u.vendor.lower(), u.product.lower(), u.serial, u.symlink, group, u.mode))
        return tuple(out)

    @staticmethod
    def _fastdds_ports(domain: int) -> tuple[int, ...]:
        """Metatraffic unicast ports (RTPS: 7400 + 250*domain + 10 + 2*participant) of participants 0..3."""
        return tuple(7400 + 250 * domain + 10 + 2 * pid for pid in range(FASTDDS_PARTICIPANT_SLOTS))

    def _deploy_root(self, host: Host, variables: Mapping[str, Any], problems: list[Problem]) -> str:
        """The robot's deploy root, as deploy reads it (Deployer.root), made absolute for logrotate,
        which does not expand "~"."""
        root = str(host.vars.get("rosdeploy_deploy_root") or self.spec.deploy_root).rstrip("/") or "/"
        if root != "~" and not root.startswith("~/"):
            return root
        home = variables.get("rosdeploy_home")
        if not home:
            home = "/root" if host.user in (None, "root") else f"/home/{host.user}"
            self._check_user_plain(host, problems)
        return str(home).rstrip("/") + root[1:]

    @staticmethod
    def _check_user_plain(host: Host, problems: list[Problem]) -> None:
        """The SSH user, read when the inventory was loaded (outside the renderer's secret_reads),
        becomes the logs' home folder in logrotate.conf: refused at its var when it comes from a
        vault, in any form (`{{ token|reverse|join }}` no longer holds the vault text)."""
        var = next((v for v in ("ansible_ssh_user", "ansible_user") if v in host.vars), None)
        if var is None:
            return
        source_of = getattr(host.vars, "secret_source", None)
        source = source_of(var) if source_of else (var if host.user in host.secret_values else None)
        if source is not None:
            problems.append(_host_problem(host, var, (
                f"a secret value would be written to {LOGROTATE_FILE}, which is not secret: the logs' home folder "
                f"/home/<user> comes from {secret_read(var, source)}; set rosdeploy_home (the user's home "
                "folder, e.g. /home/ubuntu) in a plain vars file")))

    def _tunables(self, host: Host, variables: Mapping[str, Any], problems: list[Problem]) -> dict[str, Any]:
        out = {}
        for name, (default, valid, what) in TUNABLES.items():
            with secret_reads() as read:
                value = _defined(variables.get(name, default))
            if not valid(value):
                got = shown_unless_secret(value, read)
                problems.append(self._var_problem(host, name, f"{name} must be {what}; got {got}"))
            out[name] = value
        lease, announce = out["dds_lease_duration"], out["dds_lease_announcement"]
        both = all(TUNABLES[n][1](out[n]) for n in ("dds_lease_duration", "dds_lease_announcement"))
        if self.spec.rmw == "fastdds" and both and announce >= lease:    # CycloneDDS's profile renders neither
            given = "dds_lease_announcement" if "dds_lease_announcement" in variables else "dds_lease_duration"
            problems.append(self._var_problem(host, given, (
                f"dds_lease_announcement ({announce} s) must be shorter than dds_lease_duration ({lease} s): the "
                "peers would drop this robot between two announcements (Fast DDS refuses it); make it about a "
                "third of the lease")))
        return out

    def _var_problem(self, host: Host, name: str, message: str) -> Problem:
        """At the var `name` where its value comes from: the robot's inventory, else the fleet
        file's `vars:` (where the inventory does not set it, the robot's declaration is no cause)."""
        if name not in host.vars and name in self.spec.vars:
            return self._problem(("vars", name), f"robot {shown(host.name)}: {message}")
        return _host_problem(host, name, message)

    def _file(self, out: str, template: jinja2.Template, context: Mapping[str, Any], host: Host) -> RenderedFile:
        env_secrets = _EnvSecrets(context["secrets"])
        context = {**context, "secrets": env_secrets if out == ENV_FILE else _OnlyInEnv(context["secrets"])}
        try:
            with secret_reads() as secret:
                content = template.render(context)
        except (jinja2.TemplateError, _Rejected) as exc:
            hidden = self._hidden_error(host, secret, env_secrets)
            raise RenderError([self._template_problem(exc, template, host, hidden=hidden)]) from exc
        except Exception as exc:   # 1/0, recursion, a bound: the template's fault, never an internal error
            hidden = self._hidden_error(host, secret, env_secrets)
            raise RenderError([self._template_problem(jinja2.TemplateRuntimeError(describe(exc)), template, host,
                                                      exc.__traceback__, hidden)]) from exc
        if out == ENV_FILE:
            return RenderedFile(out, content, mode=0o600, secret=bool(context["secrets"]))
        if secret:
            raise RenderError([_host_problem(host, var, f"template {template.name} writes "
                                                        f"{secret_read(var, source)} into {out}, which is not secret; "
                                                        "pass it with `secrets:` so it goes to .env only")
                               for var, source in sorted(secret.items())])
        return RenderedFile(out, content)

    def _hidden_error(self, host: Host, read: Mapping[str, str], env_secrets: _EnvSecrets) -> str | None:
        """Why a template's error is not shown, or None: it read a vault var (or a var computed from
        one), or env.j2 read a `secrets` value, before it failed."""
        if read:
            return not_quoted(*min(read.items()))
        if env_secrets._read:
            name = next(iter(env_secrets._read))
            return (f"this fails after reading secret {name} (var {shown(self.secret_vars[name])}); the error is not "
                    "shown, as it may quote the secret or a value computed from it (check the value with "
                    "`rosdeploy vault view`)")
        return None

    def _template_problem(self, exc: Exception, template: jinja2.Template, host: Host,
                          tb: Any = None, hidden: str | None = None) -> Problem:
        """Locate an error raised while rendering: the deepest frame that is template code. `hidden`:
        said instead of the error, when it must not be quoted (see _hidden_error)."""
        file, line = template.filename or template.name or "?", None
        names = {t.filename for t in self.templates.values()}
        # a partial that does not compile shows as a frame of its own (Jinja's rewritten traceback): skipped
        partial = exc.filename if isinstance(exc, jinja2.TemplateSyntaxError) else None
        for frame, lineno in traceback.walk_tb(tb or exc.__traceback__):
            filename = frame.f_code.co_filename
            if (filename in names or filename.endswith(".j2")) and filename != partial:   # included partials too
                file, line = filename, lineno
        message = getattr(exc, "message", None) or str(exc)
        if hidden:
            return Problem(file, line, "", f"robot {shown(host.name)}: {hidden}")
        included = f"included by {file}:{line}" if line else f"included by {file}"
        if isinstance(exc, jinja2.TemplateSyntaxError) and partial:
            return Problem(partial, exc.lineno, "", f"template syntax error: {exc.message} ({included})")
        if isinstance(exc, _NotATemplate):       # a partial that is a FIFO, a folder, a dangling link
            return Problem(exc.path, None, "", f"{exc.reason} ({included})")
        if isinstance(exc, jinja2.TemplateNotFound):
            return Problem(file, line, "", f"robot {shown(host.name)}: {self._not_found(str(exc.name))}")
        missing = re.search(r"'([^']+)' is undefined|has no attribute '([^']+)'", message)
        what = f"undefined name {next(g for g in missing.groups() if g)!r}" if missing else message
        return Problem(file, line, "", f"robot {shown(host.name)}: {what}" + (f" ({message})" if missing else ""))

    def _not_found(self, name: str) -> str:
        """Why an include, import or extends found no template `name`."""
        if name.startswith("/") or ".." in name.split("/"):
            return (f"template {shown(name)} is outside the template folder: include, import or extend a template "
                    "of the folder, by its name there")
        folder = f"in {self.override} nor " if self.override else ""
        return f"template {shown(name)} not found {folder}among rosdeploy's templates (check the name)"

    def _check_leaks(self, host: Host, files: Iterable[RenderedFile]) -> None:
        """compose.yml and the other files are not secret: a vault value in them is a leak. One
        problem per file, at the vault var; a store/<digest>/ copy repeats a file already searched."""
        secrets = _searched(host)
        leaked = {f.name: found for f in files if f.name != ENV_FILE and not f.secret
                  and not f.name.startswith(f"{restarts.STORE}/")
                  for found in [[s for s in secrets if s in f.content]] if found}
        if leaked:
            vault = _vault_texts(host)
            raise RenderError([self._leak_problem(host, name, texts, vault) for name, texts in sorted(leaked.items())])

    def _leak_problem(self, host: Host, name: str, texts: list[str], vault: Mapping[str, tuple[str, ...]]) -> Problem:
        """`texts` (vault texts) found in the file `name`: which vault var they are, which var carried
        them, and whether they are text the template or the fleet file holds anyway."""
        sources = sorted({var for var, held in vault.items() for text in texts if text in held})
        if not sources:    # host.vars is a plain mapping (no origins): only the robot is known
            return _host_problem(host, "", f"a secret value would be written to {name}; pass it with `secrets:` so "
                                           "it goes to .env only")
        carried = _carrier(host, sources[0], texts)
        what = secret_read(carried or sources[0], sources[0])
        if len(sources) > 1:
            what += f" (and vault var {', '.join(map(shown, sources[1:]))})"
        if any(text in public for text in texts for public in self._public_texts(name)):
            why = (f"the value of {what} is also text that the template or the fleet file writes there anyway (a "
                   "word like `true`, the version, an image name), so this may be a coincidence: give the secret a "
                   "longer, unguessable value; if the service needs it, pass it with `secrets:` (.env only)")
        else:
            why = f"{what} reaches it; pass it with `secrets:` so it goes to .env only"
        return _host_problem(host, carried or sources[0],
                             f"a secret value would be written to {name}, which is not secret: {why}")

    def _public_texts(self, name: str) -> list[str]:
        """Text that reaches the file `name` whatever the vault holds: its template's source, and every
        string of the fleet file (values, names, versions)."""
        texts = list(_strings_of(self.spec))
        template = self.templates.get(name)
        if template is not None and template.filename:
            try:
                texts.append(Path(template.filename).read_text(encoding="utf-8", errors="replace"))
            except OSError:
                pass
        return texts


def _vault_texts(host: Host) -> dict[str, tuple[str, ...]]:
    """The robot's vault vars and the texts they hold (none when host.vars is a plain mapping)."""
    if not isinstance(host.vars, HostVars):
        return {}
    raw = raw_vars(host.vars)
    return {var: tuple(text for _, text in strings(raw[var], ())) for var in raw
            if host.vars.secret_source(var) == var}


def _carrier(host: Host, source: str, texts: list[str]) -> str | None:
    """A var computed from vault var `source` whose value holds one of `texts` (the var a file
    really read, e.g. ansible_user: "{{ token }}"), if one was read; else None."""
    assert isinstance(host.vars, HostVars)      # _vault_texts found vault vars
    for var in sorted(host.vars):
        if var != source and host.vars.secret_source(var) == source:
            value = host.vars[var]
            if isinstance(value, str) and any(text in value for text in texts):
                return var
    return None


def _strings_of(value: Any, depth: int = 0) -> Iterable[str]:
    """Every string inside a fleet spec (dataclasses, mappings, sequences)."""
    if isinstance(value, str):
        yield value
    elif depth > 20:
        return
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            if f.name != "lines":
                yield from _strings_of(getattr(value, f.name), depth + 1)
    elif isinstance(value, Mapping):
        for key, item in value.items():
            yield from _strings_of(key, depth + 1)
            yield from _strings_of(item, depth + 1)
    elif isinstance(value, (list, tuple, set, frozenset)):
        for item in value:
            yield from _strings_of(item, depth + 1)


def _secret_problem(name: str, value: Any) -> str | None:
    """Why a var's value cannot be the .env value `name`, or None; never quoting the value."""
    if isinstance(value, (Mapping, list, tuple, set)):
        return (f"the var holds a {'mapping' if isinstance(value, Mapping) else 'list'}, not a string: a .env "
                "value is one line of text")
    if value is None or value == "":
        # compose.yml reads it as ${NAME:?..}, which refuses an empty value on the robot; and None would
        # be written as the text `None` (Ansible renders a null as empty)
        return (f"the var is {'null' if value is None else 'empty'}, and compose refuses an empty {name} on the "
                "robot: give it a value in the vault file")
    try:
        env_value(value)
    except _Rejected as exc:
        return str(exc)
    return None


def _defined(value: Any) -> Any:
    """A var whose template failed reads as an Undefined that carries its error (file, key, why):
    raise it, rather than judge the Undefined as a wrong value ("got Undefined")."""
    if isinstance(value, jinja2.Undefined):
        value._fail_with_undefined_error()
    return value


_TO_SECRETS = "move {key} to the service's `secrets:` ({key}: <inventory var>) so it goes to .env only"


_HOSTNAME = re.compile(r"(?=.{1,253}\Z)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                       r"(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?", re.ASCII)


def _is_peer_address(peer: str) -> bool:
    """An IPv4/IPv6 address or an RFC 1123 host name: what a DDS locator or <Peer address> takes."""
    try:
        ipaddress.ip_address(peer)
        return True
    except ValueError:     # digits and dots only are meant as IPv4 (`256.1.1.1`), not as a name
        return not re.fullmatch(r"[0-9.]+", peer) and bool(_HOSTNAME.fullmatch(peer))


def _is_ipv4(peer: str) -> bool:
    return _ip_version(peer) == 4


def _is_ipv6(peer: str) -> bool:
    """An IPv6 address (a zone like `%eth0` included): a locator of its own kind, udpv6 or udp6."""
    return _ip_version(peer) == 6


@functools.lru_cache(maxsize=4096)
def _ip_version(peer: str) -> int:
    """4 or 6 for an IP address, 0 for a name: cached, as every robot's peers are read per robot."""
    try:
        return ipaddress.ip_address(peer).version
    except ValueError:
        return 0


def _searched(host: Host) -> list[str]:
    """The vault texts to look for in what was rendered: those of the vault vars read so far (the
    inventory tells once it was loaded; a plain mapping in a unit test: all of them)."""
    read = getattr(host.vars, "secret_texts_read", None)
    return [s for s in (read() if read else host.secret_values) if len(s) >= MIN_LEAK_CHECK]


def image_var(service: str) -> str:
    """.env variable holding a service's image ref: driver-node -> DRIVER_NODE_IMAGE."""
    return re.sub(r"[^A-Za-z0-9]", "_", service).upper() + "_IMAGE"


def render(spec: FleetSpec, host: Host) -> RenderedRelease:
    """One-off convenience; build a Renderer once to render many robots."""
    return Renderer(spec).render(host)
