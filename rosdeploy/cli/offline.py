"""Commands that never touch a robot: validate, render, check.

    validate FLEET   is this fleet deployable? (exit 0 with one OK line, or 2 and every problem)
    render FLEET     write what each robot would receive into --out DIR, print digests
    check FLEET      the deployment checklist: every finding with severity, rule and fix
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from rosdeploy.cli.common import add_command, add_fleet_args, inventory_targets, path_arg, warnings_json
from rosdeploy.cli.vault import load_masked
from rosdeploy.errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, InputError, Problem
from rosdeploy.output import Output, one_line

if TYPE_CHECKING:   # model.py costs 7 ms of dataclasses at import; --help needs none of it
    from rosdeploy.model import Host, RenderedRelease


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "validate", "check the fleet file and inventory; exit 2 on any error",
                    "Load the fleet file and inventory and run every error-level check. Nothing is contacted.",
                    (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL),
                    "rosdeploy validate playbooks/warehouse.yml "
                    "--vault-password-file inventory/warehouse/.vault-password-example",
                    {EXIT_OK: "deployable (warnings may be printed)"})
    add_fleet_args(p)
    p.set_defaults(func=cmd_validate)

    p = add_command(sub, "render", "write each robot's files into a folder, print their digests",
                    "Render compose.yml, .env, the DDS profile, logrotate and udev rules into DIR/<robot>/ "
                    "exactly as a deploy would upload them. Nothing is contacted.",
                    (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL), "rosdeploy render playbooks/demo.yml --out /tmp/rendered")
    add_fleet_args(p)
    p.add_argument("-o", "--out", required=True, type=path_arg, metavar="DIR",
                   help="folder to write DIR/<robot>/<file> into")
    p.set_defaults(func=cmd_render, acts=True)     # its product is the folder (_after_lost_output)

    p = add_command(sub, "check", "run the deployment checklist; exit 2 if any error",
                    "Every rule of the ROS 2 deployment checklist over the fleet file, the inventory and each "
                    "robot's rendered files, each finding with its severity, rule and fix.",
                    (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL), "rosdeploy check playbooks/demo.yml --limit robot1",
                    {EXIT_OK: "no error-level finding (warnings and infos may be printed)",
                     EXIT_INPUT: "an error-level finding, or an input error"})
    add_fleet_args(p)
    p.set_defaults(func=cmd_check)


def _load(args: argparse.Namespace, out: Output, pick_up: bool = False,
          ) -> tuple[Any, tuple[Host, ...], tuple[Problem, ...]]:
    """The project, its robots, and the warnings of loading them (common.inventory_targets).
    `pick_up` (validate, check): with --limit, the robots pending for this version too, which
    `apply` with the same --limit takes (render writes only the robots asked for)."""
    project = load_masked(args, out, args.release_version)
    hosts, warnings = inventory_targets(project, args.limit, out)
    if pick_up and args.limit is not None:
        from rosdeploy.cli import pending as pending_cli
        hosts = pending_cli.with_pending(project, hosts, out, doing="validating")
    return project, hosts, warnings


# ---------------------------------------------------------------- validate

def cmd_validate(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.project import validate

    project, hosts, loaded = _load(args, out, pick_up=True)
    problems = validate(project, hosts)
    errors = [p for p in problems if p.severity == "error"]
    if out.as_json:
        out.document({"ok": not errors, "fleet": args.fleet, "project": project.spec.project,
                      "version": project.spec.version, "robots": [h.name for h in hosts],
                      "problems": _problems_json(problems, loaded), **failed_json(errors)})
    else:
        _print_problems(out, problems)     # the loading warnings were printed as they came
    if errors:
        out.error(f"{len(errors)} error(s): not deployable; fix the files above and run validate again")
        return EXIT_INPUT
    spec = project.spec
    warned = len(problems) - len(errors) + len(loaded)
    out.line(f"OK {args.fleet}: project {spec.project} version {spec.version}, {len(spec.services)} service(s), "
             f"{len(hosts)} robot(s)" + (f", {warned} warning(s)" if warned else ""))
    return EXIT_OK


def _problems_json(problems: Sequence[Problem], loaded: Sequence[Problem]) -> list[dict[str, Any]]:
    """The rules' problems and the warnings of loading the robots, in one list in the rules' order
    (errors first), as `--json` readers find every warning in it."""
    from rosdeploy import checks
    return [problem_json(p) for p in sorted([*problems, *loaded], key=checks.sort_key)]


def _print_problems(out: Output, problems: Sequence[Problem]) -> None:
    for p in problems:
        (out.error if p.severity == "error" else out.warn)(f"{p.severity}: {p}")


# ------------------------------------------------------------------ render

def cmd_render(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.project import deployable

    project, hosts, loaded = _load(args, out)
    warnings_json(out, loaded)      # in the document of a render the fleet's errors stop, too
    root = Path(args.out)
    _check_out(root, Path(project.spec.inventory), [host.name for host in hosts])
    releases, warnings = _render_to(root, lambda sink: deployable(project, hosts, sink))   # or exit 2
    for warning in warnings:
        out.warn(f"{warning.severity}: {warning}")
    warnings_json(out, [*loaded, *warnings])
    written = [root / name for name in releases]
    if out.as_json:
        robots = [_release_json(r, d) for r, d in zip(releases.values(), written, strict=True)]
        out.document({"out": str(root), "robots": robots})
        return EXIT_OK
    out.table(["ROBOT", "RELEASE", "DIGEST", "FILES"],
              [(r.host, r.release_id, r.digest[:16], len(r.files)) for r in releases.values()])
    out.line(f"wrote {len(releases)} robot(s) to {one_line(root)}/<robot>/")   # a newline in --out: still one line
    return EXIT_OK


def _check_out(root: Path, inventory: Path, robots: Sequence[str]) -> None:
    """--out may not be / (robot `etc` would merge its logrotate.conf & co into /etc), nor a
    folder the inventory is read from (the next run would read the robots' files as inventory),
    nor hold one as a robot's folder: `--out .` beside the inventory writes robot `group_vars`
    into ./group_vars, whose compose.yml the next run reads as the vars of group `compose`."""
    out = os.path.realpath(root)
    if out == "/":
        raise InputError([Problem(str(root), None, "--out", "the filesystem root: render writes a folder "
                                  "per robot into --out; give a folder of its own, e.g. /tmp/release")])
    read = _read_folders(inventory)
    inside = _inside(out, read)
    if inside is not None:
        raise InputError([Problem(str(root), None, "--out", f"inside {inside}, which the inventory is read from: "
                                  "the next run would read the rendered files as inventory; give a folder "
                                  "outside it, e.g. /tmp/release")])
    problems = [Problem(str(root / robot), None, "--out", f"robot {robot}'s folder is {folder}, which the "
                        "inventory is read from: the next run would read its files as inventory; give a folder "
                        "of its own, e.g. /tmp/release")
                # the robot's own name not followed: writeout refuses a link there, in its own words
                for robot in robots for folder in [_inside(os.path.join(out, robot), read)] if folder]
    if problems:
        raise InputError(problems)


def _read_folders(inventory: Path) -> list[str]:
    """The folders the inventory is read from: the inventory folder itself, or group_vars/ and
    host_vars/ beside an inventory file."""
    base = os.path.realpath(inventory if inventory.is_dir() else inventory.parent)
    return [base] if inventory.is_dir() else [os.path.join(base, "group_vars"), os.path.join(base, "host_vars")]


def _inside(path: str, folders: Sequence[str]) -> str | None:
    """The first of `folders` that `path` is or lies in, or None."""
    return next((folder for folder in folders if os.path.commonpath([path, folder]) == folder), None)


def _render_to(root: Path, render: Callable[[Any], tuple[dict[str, RenderedRelease], list[Problem]]],
               ) -> tuple[dict[str, RenderedRelease], list[Problem]]:
    """Render (every rule run) and write each robot's folder under root as it is rendered
    (writeout.Staged). Nothing lands when a rule refuses, and the fleet's own errors come before
    any "cannot write"."""
    from rosdeploy.cli import writeout

    try:
        staged = writeout.Staged(root)
    except OSError as exc:    # --out is a file, read-only...: said after the fleet's own errors
        render(None)
        raise writeout.cannot_write(exc, root) from None
    done = False
    try:
        releases, warnings = render(staged.write)
        done = True
    finally:
        try:
            staged.finish(done, releases if done else ())
        except OSError as exc:
            if done:                    # else the run's own error is on its way out
                raise writeout.cannot_write(exc, root) from None
    return releases, warnings


def _release_json(release: RenderedRelease, folder: Path) -> dict[str, Any]:
    return {"robot": release.host, "release": release.release_id, "digest": release.digest, "dir": str(folder),
            "images": list(release.images),
            "files": [{"name": f.name, "mode": f"{f.mode:04o}"} for f in release.files]}


# ------------------------------------------------------------------- check

def cmd_check(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.project import findings

    project, hosts, loaded = _load(args, out, pick_up=True)
    problems = findings(project, hosts)
    errors = sum(p.severity == "error" for p in problems)
    if out.as_json:
        out.document({"ok": not errors, "fleet": args.fleet, "robots": [h.name for h in hosts],
                      "findings": _problems_json(problems, loaded),
                      **failed_json([p for p in problems if p.severity == "error"])})
        return EXIT_INPUT if errors else EXIT_OK
    colors = {"error": "red", "warning": "yellow", "info": "dim"}
    for p in problems:   # the findings are this command's output: stdout, so `check > report.txt` works
        out.line(out.paint(f"{p.severity}[{p.rule or 'input'}] {p}", colors.get(p.severity, "bold")))
    from rosdeploy import checks
    # the loading warnings were printed (on stderr) as they came, and are counted with the findings
    counts = {s: sum(p.severity == s for p in (*problems, *loaded)) for s in checks.SEVERITIES}
    tally = ", ".join(f"{n} {s}(s)" for s, n in counts.items() if n) or "no findings"
    out.line(f"{'FAIL' if errors else 'OK'} {args.fleet}: {len(hosts)} robot(s), {tally}")
    return EXIT_INPUT if errors else EXIT_OK


def failed_json(errors: Sequence[Problem]) -> dict[str, Any]:
    """The `error` member of a document whose command found `errors` (none: no member), the one a
    raised InputError gets (cli._fail): a failing rule and a file that would not load were two
    shapes of `validate --json`, and CI reads `error.problems` for both."""
    if not errors:
        return {}
    return {"error": {"kind": "input", "message": "\n".join(str(p) for p in errors),
                      "problems": [problem_json(p) for p in errors]}}


def problem_json(p: Problem) -> dict[str, Any]:
    from rosdeploy import checks
    rule = checks.RULES.get(p.rule)
    return {"severity": p.severity, "rule": p.rule or None, "file": p.file, "line": p.line, "key": p.key,
            "message": p.message, "fix": rule.fix if rule else None}
