"""A fleet file with its inventory loaded: what every command starts from.

    load_project(fleet) -> Project(spec, inventory)
    project.targets(limit) -> the robots a command acts on
    deployable(project, hosts) -> releases + warnings, or InputError with every error
    findings(project, hosts) -> everything `check` reports; validate(...) -> what `validate` reports

`deployable` is the only way to get releases to write or deploy (`render`, `plan`, `apply`,
`status`): it renders every robot and runs every rule of `check` on the result, and any
error-level finding (a duplicate domain id, `privileged` without `allow_privileged`, the
Docker socket mounted, a render error) stops the command before anything is written or
touched. So a command cannot forget the validation `validate` and `check` run.
"""
from __future__ import annotations

import functools
import gc
from contextlib import closing, contextmanager
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

from rosdeploy import forked
from rosdeploy.errors import InputError, Problem, RenderError
from rosdeploy.fleet import load_fleet
from rosdeploy.inventory import Inventory, load_inventory
from rosdeploy.model import FleetSpec, Host, RenderedRelease
from rosdeploy.vault import Vault

if TYPE_CHECKING:
    from rosdeploy.checks import TargetRules
    from rosdeploy.render import Renderer

# Scopes whose rules judge the inputs (fleet file + inventory) rather than a rendered release:
# validate reports their warnings too, since the fix is in the user's own files.
INPUT_SCOPES = ("fleet", "host")
OnRelease = Callable[[RenderedRelease], None] | None


@dataclass(frozen=True)
class Project:
    spec: FleetSpec
    inventory: Inventory
    # the vault passwords read: they key the digests of secret content (model.secret_key), so a
    # digest on a robot is no test of a guess of a short secret; never written anywhere
    vault_passwords: tuple[bytes, ...] = field(default=(), repr=False)

    def targets(self, limit: str | None = None, warnings: list[Problem] | None = None) -> tuple[Host, ...]:
        """The robots `--limit` selects (all of them without one), in inventory order; a term that
        matches nothing is a warning appended to `warnings` (as in Ansible)."""
        return tuple(self.inventory.select(limit, warnings))

    @property
    def secret_values(self) -> frozenset[str]:
        """Every vault value of every robot: what output must mask."""
        return frozenset().union(*(h.secret_values for h in self.inventory.hosts.values()))


# `checks` and `render` (Jinja2) are imported where they are used: an emergency rollback
# loads the project but renders and checks nothing, and each command is a new process.
def load_project(fleet_path: str, *, inventory: str | None = None, version: str | None = None,
                 vault_password_file: str | None = None, prompt: Callable[[str], str] | None = None,
                 vault: Vault | None = None) -> Project:
    """Load the fleet file, then its inventory (decrypting vault files with the password sources).

    `vault`, when given (e.g. several --vault-id, see cli.vault.vault_from_args), replaces the
    password file and prompt arguments."""
    with gc_paused():
        spec = load_fleet(fleet_path, inventory=inventory, version=version)
        vault = vault or Vault(password_file=vault_password_file, prompt=prompt)
        inventory_ = load_inventory(spec.inventory, vault=vault)
        return Project(spec, inventory_, vault.read_passwords())


@contextmanager
def gc_paused() -> Iterator[None]:
    """The cyclic garbage collector off while a stage builds data it keeps.

    Loading and rendering 5,000 robots keep about a million small objects alive, and each of the
    collector's full passes walks all of them: a quarter of the CPU time of `render` and `check`
    (issue 18, bench/validate_bench.py). These stages make no reference cycles worth collecting
    (the peak RSS is the same within 3%). When the collector resumes, what the stage built is
    frozen (gc.freeze: left out of every later collection, still freed when unreferenced);
    otherwise the first collection after would walk all of it at once.
    """
    if not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


def deployable(project: Project, hosts: Sequence[Host], on_release: OnRelease = None,
               ) -> tuple[dict[str, RenderedRelease], list[Problem]]:
    """Every robot's release and the input warnings, after every rule ran; InputError on any error.
    `on_release`: called with each release as soon as it is rendered, before any rule ran, in the
    process that rendered it: a forked child for a large fleet, so what it does must land outside
    this process's memory (render's files). It may run twice for a robot whose child failed."""
    releases, problems = prepare(project, hosts, on_release)
    problems = gate(problems)
    errors = [p for p in problems if p.severity == "error"]
    if errors:
        raise InputError(errors)
    return releases, problems


def _address_key(project: Project) -> bytes | None:
    """The key of secret content's digests: from the vault passwords, else (none was read, so no
    vault value exists) each robot's own vault values (model.secret_key)."""
    from rosdeploy.model import secret_key
    if not project.vault_passwords:
        return None
    return secret_key(frozenset(p.decode("latin-1") for p in project.vault_passwords))


OnTargets = dict[str, list[tuple[Problem, str]]]     # rule id -> [(finding, robot)], robots in order


def _render_all(project: Project, hosts: Sequence[Host], on_release: OnRelease = None,
                ) -> tuple[dict[str, RenderedRelease], list[Problem], OnTargets]:
    """Render every robot whose inputs allow it: the releases, the render errors, and what the
    release and service rules find on each release (checks.TargetRules, run where it rendered).

    A robot failing an input rule (a device or secret it lacks) is skipped: the rule
    already says what is wrong, in better words than the renderer could.
    """
    from rosdeploy import checks
    from rosdeploy.render import Renderer
    blocked = checks.blocked_hosts(project.spec, hosts)
    try:
        renderer = Renderer(project.spec, secret_key=_address_key(project))
    except RenderError as exc:
        return {}, list(exc.problems), {}
    releases: dict[str, RenderedRelease] = {}
    failed: dict[tuple, tuple[Problem, list[str]]] = {}
    on_targets: OnTargets = {}
    todo = [host for host in hosts if host.name not in blocked]
    work = functools.partial(_render_one, renderer, checks.TargetRules(project.spec), on_release)
    # closing(): on any way out, the children are ended before the caller cleans up after them
    with closing(forked.mapped(work, todo)) as outcomes:
        for host, (outcome, found) in zip(todo, outcomes, strict=True):
            if isinstance(outcome, RenderedRelease):
                releases[host.name] = outcome
                for rule_id, p in found:
                    on_targets.setdefault(rule_id, []).append((p, host.name))
                continue
            for p in outcome:
                same = (p.file, p.line, p.key, p.message.replace(host.name, ""))
                failed.setdefault(same, (p, []))[1].append(host.name)
    return releases, [_same_on(p, robots) for p, robots in failed.values()], on_targets


def _render_one(renderer: Renderer, rules: TargetRules, on_release: OnRelease, host: Host,
                ) -> tuple[RenderedRelease | tuple[Problem, ...], tuple[tuple[str, Problem], ...]]:
    """One robot's release and what the release rules find on it, or what stops it (values that
    pickle: forked.mapped may run this in a child, and on_release with it)."""
    try:
        release = renderer.render(host)
    except RenderError as exc:
        return tuple(exc.problems), ()
    if on_release is not None:
        on_release(release)
    return release, rules(host, release)


def _same_on(p: Problem, robots: list[str]) -> Problem:
    """A template bug fails every robot the same way: one problem, counting the others."""
    if len(robots) == 1:
        return p
    return replace(p, message=f"{p.message} (the same on {len(robots) - 1} more robot(s))")


def prepare(project: Project, hosts: Sequence[Host], on_release: OnRelease = None,
            ) -> tuple[dict[str, RenderedRelease], list[Problem]]:
    """Render every robot once and run every rule on the result: releases and findings, errors first."""
    from rosdeploy import checks, ready
    with gc_paused():
        releases, problems, on_targets = _render_all(project, hosts, on_release)
        problems += ready.host_problems(project.spec, hosts)     # inventory `ready:` / `window:` overrides
        found = checks.run_checks(project.spec, hosts, releases, all_hosts=tuple(project.inventory.hosts.values()),
                                  on_targets=on_targets)
    return releases, sorted(problems + found, key=checks.sort_key)


def findings(project: Project, hosts: Sequence[Host]) -> list[Problem]:
    """Everything `check` reports: render errors and every rule's findings, errors first."""
    return prepare(project, hosts)[1]


def validate(project: Project, hosts: Sequence[Host]) -> list[Problem]:
    """What must stop a deploy (errors), plus the warnings about the inputs themselves."""
    return gate(findings(project, hosts))


def gate(problems: Sequence[Problem]) -> list[Problem]:
    return [p for p in problems if p.severity == "error" or _is_input_rule(p)]


def _is_input_rule(p: Problem) -> bool:
    from rosdeploy import checks
    rule: Any = checks.RULES.get(p.rule)
    return rule is not None and rule.scope in INPUT_SCOPES
