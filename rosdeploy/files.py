"""Per-robot files (the fleet file's `files:`): rendered or copied per robot, mounted read-only.

A params YAML per robot (`template: params/{{ inventory_hostname }}.yaml`), a map copied
as is (`copy: maps/{{ site }}.yaml`), camera or LiDAR calibration from host_vars
(`var: camera_calibration`). Each lands in the release twice: files/<name>, which `plan`
diffs against the running release, and store/<digest>/<file>, which the services that
name it mount read-only (see rosdeploy.restarts: the same content keeps the same path, so
a change recreates only the services that mount it). Both are part of the release digest,
so they roll back with the release.

Source paths are the fleet repo's: relative to the fleet file, rendered per robot in the
sandbox, and refused when they leave the fleet file's folder (`..`, an absolute path, or a
symbolic link pointing out).
"""
from __future__ import annotations

import re
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import jinja2
import yaml

from rosdeploy import restarts
from rosdeploy.errors import Problem, shown
from rosdeploy.inventory.templating import secret_read, secret_reads, unless_secret
from rosdeploy.model import FleetSpec, Host, RenderedFile, RobotFile
from rosdeploy.sandbox import Layered, render_value, value_template
from rosdeploy.vault import is_password_file
from rosdeploy.yamlsrc import Doc

FILES_DIR = "files"
MAX_BYTES = 50 * 1024 * 1024      # a release is uploaded whole on every deploy
# A template (a `template:` file, a template folder's file) is a page of layout, compiled whole
# before any bound of the sandbox applies: 10 MB of one took 47 s and 327 MB.
MAX_TEMPLATE_BYTES = 1 << 20


# Plain scalars some reader of a written file takes for a number, though PyYAML (YAML 1.1) writes
# them bare as strings: YAML 1.2 (Compose v2's go-yaml v3, yaml-cpp) reads `1e3`, `0o17`, `.5`;
# go-yaml v3 first drops every `_` (`1_e3`, `0_x1`) and takes `0X1F`, `0B1`, `0O17`; ROS 2's
# rcl_yaml_param_parser reads a plain scalar with C's strtol/strtod (hex floats, `inf`, `nan`,
# `infinity` in any case). Matched after dropping `_`, case-insensitively.
_NUMBER_START = frozenset("0123456789+-.")
_NUMBER = re.compile(r"""[-+]?(?:
      0x[0-9a-f]*\.?[0-9a-f]*(?:p[-+]?[0-9]+)?                # hex int; C's hex float
    | 0o[0-7]+ | 0b[01]+
    | (?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:e[-+]?[0-9]+)?       # decimal int and float: 1, 1., .5, 1e3
    | [0-9]+(?::[0-5]?[0-9])+(?:\.[0-9]*)?                     # YAML 1.1 base 60: 1:20
    | \.?(?:inf|infinity|nan)
)""", re.X | re.I)
# Plain words YAML 1.1 (y, n, on, off, yes, no: Compose v1, ROS 2's parser), YAML 1.2 or strtod
# read as a bool, null or float; in any case: a reader that takes `True` may take `TRUE`.
_WORDS = frozenset("y n yes no on off true false null ~ inf infinity nan".split())
_LONGEST_WORD = max(map(len, _WORDS))


def reads_as_number(text: str) -> bool:
    """True when some reader takes `text`, written as a plain scalar, for a number (_NUMBER)."""
    return text[:1] in _NUMBER_START and _NUMBER.fullmatch(text.replace("_", "")) is not None


def reads_as_other(text: str) -> bool:
    """True when some YAML reader (1.1 or 1.2) or ROS 2's parameter parser would read `text`,
    written as a plain scalar, as something other than this string: write it quoted. Most
    strings are decided by their first character and length, with no regex."""
    if not text:
        return True    # a null
    if text[0] in _NUMBER_START:
        return reads_as_number(text)
    return len(text) <= _LONGEST_WORD and text.lower() in _WORDS


def represent_text(dumper: yaml.SafeDumper, data: str) -> yaml.ScalarNode:
    """A string for a YAML Dumper: quoted when reads_as_other (the emitter may still choose double
    quotes where single ones cannot hold it). A str subclass the loader made (an `!unsafe`
    scalar, a decrypted vault value) is written as the text it is, as Ansible's to_yaml writes it."""
    return dumper.represent_scalar("tag:yaml.org,2002:str", data, style="'" if reads_as_other(data) else None)


class _Dumper(yaml.SafeDumper):
    """YAML of an inventory value, which a reader of YAML 1.2 or ROS 2's parameter parser may read."""


_Dumper.add_representer(str, represent_text)
_Dumper.add_multi_representer(str, represent_text)


class _Included(jinja2.TemplateError):
    """An include, import or extends in a `files:` template (_NoOtherTemplates)."""

    def __init__(self, name: str) -> None:
        super().__init__(f"template {name}")
        self.name = name


class _NoOtherTemplates(jinja2.BaseLoader):
    """A `files:` template's loader, which loads nothing. The renderer's would look in the
    `templates:` folder and among rosdeploy's own templates, not beside the file (its path is
    relative to the fleet file): an include there would take a partial of another set, or
    rosdeploy's compose.yml.j2, unseen. README ("Per-robot files"): a `files:` template is whole."""

    def get_source(self, environment: jinja2.Environment, template: str) -> tuple[str, str, Any]:
        raise _Included(template)


_TAG = re.compile(r"\{%[-+]?\s*(?:include|import|from|extends)\b.*?%\}", re.S)


def _tag_line(template: jinja2.Template, text: str, exc: BaseException) -> tuple[int | None, str]:
    """(line, the tag's text) of the include, import or extends that raised `exc`: the line from
    the compiled template's frame (render_value runs it without Jinja's traceback rewriting), else
    that of the source's only such tag; None when it cannot be told."""
    line = None
    for frame, lineno in traceback.walk_tb(exc.__traceback__):
        if frame.f_code.co_filename == "<template>":
            line = template.get_corresponding_lineno(lineno)
    tags = [(text.count("\n", 0, m.start()) + 1, m.group()) for m in _TAG.finditer(text)]
    if line is None and len(tags) == 1:
        line = tags[0][0]
    on_line = [tag for at, tag in tags if at == line]
    tag = on_line[0] if len(on_line) == 1 and len(on_line[0]) <= 120 and "\n" not in on_line[0] else ""
    return line, tag


@dataclass(frozen=True)
class RobotFiles:
    """One robot's files: what goes into the release, and each service's mounts."""

    files: tuple[RenderedFile, ...]
    mounts: Mapping[str, tuple[str, ...]]     # service -> ("../../store/<digest>/<file>:<target>:ro", ...)
    secret_values: frozenset[str]


class FileRenderer:
    """Compiles the path templates once; `render(host, variables)` per robot."""

    def __init__(self, spec: FleetSpec, env: jinja2.Environment) -> None:
        self.spec, self.env = spec, env
        self.base = Path(spec.path).resolve().parent
        used = {name for svc in spec.services for name in svc.files}
        self.entries = tuple(f for f in spec.files if f.name in used)
        self.paths = {f.name: value_template(env, f.source) for f in self.entries if f.kind != "var"}
        self.file_env = env.overlay(loader=_NoOtherTemplates())    # the same sandbox and filters
        self._cache: dict[Path, str] = {}
        self._templates: dict[Path, jinja2.Template] = {}

    def render(self, host: Host, variables: Mapping[str, Any], problems: list[Problem], key: bytes) -> RobotFiles:
        """`key`: model.secret_key, for the store address of a secret file."""
        names = {"vars": variables, "host": host, "inventory_hostname": host.name}
        out: list[RenderedFile] = []
        stored: dict[str, str] = {}
        secrets: set[str] = set()
        for entry in self.entries:
            with secret_reads() as secret:
                content = self._content(entry, host, (names, variables), problems)
            if content is None:
                continue
            if secret and not entry.secret:
                problems.append(self._problem(host, entry, f"{secret_read(*min(secret.items()))} would be "
                                                           "written to this file, which is not "
                                                           "secret: add `secret: true` to it (mode 0600, masked)"))
                continue
            if entry.secret:   # masked in plan's diffs: the vault values, and what was computed from them
                secrets.update(text for var in secret if isinstance(text := variables.get(var), str))
            mode = 0o600 if entry.secret else 0o644
            plain = RenderedFile(f"{FILES_DIR}/{entry.name}", content, mode=mode, secret=entry.secret)
            copy = restarts.stored(plain, entry.target.rsplit("/", 1)[-1], key)
            out += [plain, copy]
            stored[entry.name] = f"{restarts.mount_source(copy)}:{entry.target}:ro"
            if entry.secret:
                secrets.update(s for s in host.secret_values if s and s in content)
        mounts = {svc.name: tuple(stored[n] for n in svc.files if n in stored) for svc in self.spec.services}
        return RobotFiles(tuple(out), mounts, frozenset(secrets))

    def _problem(self, host: Host, entry: RobotFile, message: str) -> Problem:
        doc = Doc(self.spec.path, None, self.spec.lines)
        return doc.problem(("files", entry.name, entry.kind), f"robot {shown(host.name)}: {message}")

    def _content(self, entry: RobotFile, host: Host, layers: tuple[Mapping[str, Any], ...],
                 problems: list[Problem]) -> str | None:
        scope = Layered(*layers)
        if entry.kind == "var":
            if entry.source not in scope:
                problems.append(self._problem(host, entry, f"inventory variable {shown(entry.source)} is not defined "
                                                           "for this robot: set it in its host_vars or group_vars"))
                return None
            value = scope[entry.source]
            if isinstance(value, jinja2.Undefined):   # its template failed: reading it says why
                try:
                    str(value)
                except jinja2.TemplateError as exc:
                    problems.append(self._problem(host, entry, exc.message or str(exc)))
                    return None
                # An Undefined that reads as "" (not strict) must not become an empty file, nor reach yaml.
                problems.append(self._problem(host, entry, f"inventory variable {shown(entry.source)} is undefined for "
                                                           "this robot: check its template in host_vars or group_vars"))
                return None
            return str(value) if isinstance(value, str) else self._yaml(value, host, entry, problems)
        rel = self._path(entry, host, layers, problems)
        if rel is None:
            return None
        path = self._checked(rel, host, entry, problems)
        if path is None:
            return None
        text = self._read(path, host, entry, problems)
        if text is None or entry.kind == "copy":
            return text
        if len(text) > MAX_TEMPLATE_BYTES:     # characters: at most as many as bytes
            problems.append(self._problem(host, entry, f"{path} is over {MAX_TEMPLATE_BYTES >> 20} MiB, too large for "
                                                       "a template: use `copy:` for a file that needs no templating"))
            return None
        try:
            template = self._templates.get(path) or self._templates.setdefault(path, self.file_env.from_string(text))
            return render_value(template, *layers)
        except _Included as exc:
            at, tag = _tag_line(template, text, exc)
            problems.append(Problem(str(path), at, ".".join(("files", entry.name, entry.kind)), (
                f"robot {shown(host.name)}: {tag + ': ' if tag else ''}a files: template cannot include, import or "
                f"extend other templates (here {shown(exc.name)}): put the text in the file itself")))
            return None
        except jinja2.TemplateError as exc:
            lineno = getattr(exc, "lineno", None)
            line = f" line {lineno}" if lineno else ""
            problems.append(self._problem(host, entry, f"{path}{line}: {unless_secret(exc.message or str(exc))}"))
            return None

    def _yaml(self, value: Any, host: Host, entry: RobotFile, problems: list[Problem]) -> str | None:
        """An inventory value as YAML; a value that is not plain data (`{{ range(3) }}`) is named by
        its type only: the value may hold a secret."""
        try:
            return yaml.dump(value, Dumper=_Dumper, sort_keys=True, default_flow_style=False)
        except (yaml.YAMLError, TypeError, ValueError, RecursionError) as exc:
            odd = exc.args[1] if isinstance(exc, yaml.representer.RepresenterError) and len(exc.args) > 1 else None
            kind = f"a {type(odd).__name__} object" if odd is not None else "a value"
            problems.append(self._problem(host, entry, f"inventory variable {shown(entry.source)} holds {kind}, which "
                                                       "YAML cannot write: make it text, numbers, lists and mappings"))
            return None

    def _path(self, entry: RobotFile, host: Host, layers: tuple[Mapping[str, Any], ...],
              problems: list[Problem]) -> str | None:
        """The source path rendered; refused if it reads a vault var: a path is no secret (messages
        and plans show it), and whatever is computed from a secret must not be shown."""
        with secret_reads() as read:
            try:
                rel = render_value(self.paths[entry.name], *layers)
            except jinja2.TemplateError as exc:
                problems.append(self._problem(host, entry, unless_secret(exc.message or str(exc))))
                return None
        if read:
            problems.append(self._problem(host, entry, f"the path reads {secret_read(*min(read.items()))}: a path "
                                                       "is not secret, name the file without vault vars"))
            return None
        return rel

    def _checked(self, rel: str, host: Host, entry: RobotFile, problems: list[Problem]) -> Path | None:
        """The source file, only if it is inside the fleet file's folder (links resolved)."""
        if not rel or rel.startswith(("/", "~")) or ".." in rel.split("/"):
            problems.append(self._problem(host, entry, f"{shown(rel)} is not a path inside the fleet repo "
                                                       "(relative, without `..`)"))
            return None
        # Before any filesystem call, which raises on these: resolve() on a NUL (ValueError), stat() on
        # a name past Linux's PATH_MAX 4096 or NAME_MAX 255 bytes (OSError 36, then blamed on --out).
        full = str(self.base / rel).encode("utf-8", "surrogateescape")
        unusable = ("contains a NUL byte" if b"\0" in full else "is over 4096 bytes long" if len(full) > 4096
                    else "has a folder or file name over 255 bytes" if max(map(len, full.split(b"/"))) > 255
                    else "")
        if unusable:
            head = repr(rel) if len(rel) <= 60 else repr(rel[:57]) + "..."
            problems.append(self._problem(host, entry, f"the path renders to {head}, which {unusable}: fix "
                                                       "the template or the inventory variables it uses"))
            return None
        try:
            path = (self.base / rel).resolve()
            inside, regular, found = path.is_relative_to(self.base), path.is_file(), path.exists()
        except (OSError, RuntimeError) as exc:     # a symbolic link loop (RuntimeError before Python 3.13)
            problems.append(self._problem(host, entry, f"{self.base / rel} cannot be opened ({exc}): fix the "
                                                       "path or the link"))
            return None
        if not inside:
            problems.append(self._problem(host, entry, f"{rel} leads out of {self.base} (a symbolic link?): "
                                                       "keep the file in the fleet repo"))
            return None
        if regular and is_password_file(path):   # its text unlocks every vault; release files are world-readable
            problems.append(self._problem(host, entry, f"{rel} is a vault password file: it never goes into a "
                                                       "release; name another file"))
            return None
        if found and not regular:
            problems.append(self._problem(host, entry, f"{self.base / rel} is not a regular file (a folder, fifo "
                                                       "or device): name a file of the fleet repo"))
            return None
        if not regular:
            problems.append(self._problem(host, entry, f"{self.base / rel} does not exist: add it to the fleet "
                                                       "repo, or fix the path"))
            return None
        return path

    def _read(self, path: Path, host: Host, entry: RobotFile, problems: list[Problem]) -> str | None:
        if path not in self._cache:
            # Size first, then a bounded read: read_bytes() of a sparse 3 GB file filled memory before
            # the check, and the file may grow after stat(). _checked let regular files only through.
            try:
                with path.open("rb") as handle:
                    data = handle.read(MAX_BYTES + 1) if path.stat().st_size <= MAX_BYTES else None
            except OSError as exc:
                problems.append(self._problem(host, entry, f"cannot read {path}: {exc.strerror or exc}"))
                return None
            if data is None or len(data) > MAX_BYTES:
                problems.append(self._problem(host, entry, f"{path} is over {MAX_BYTES >> 20} MB"))
                return None
            try:
                self._cache[path] = data.decode("utf-8")
            except UnicodeDecodeError:
                problems.append(self._problem(host, entry, f"{path} is not UTF-8 text: binary files (e.g. .pgm "
                                                           "maps) are not supported yet; mount them from the robot "
                                                           "with `volumes:`"))
                return None
        return self._cache[path]

