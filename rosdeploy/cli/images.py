"""`rosdeploy bundle`, and the image supply every apply and plan starts with (docs/images.md)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from rosdeploy.cli.common import add_command, add_fleet_args, path_arg
from rosdeploy.errors import EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, InputError, Problem
from rosdeploy.output import Output, one_line

if TYPE_CHECKING:   # model.py and images.refs are the handlers' (--help builds this parser)
    from rosdeploy.model import FleetSpec, Host, RenderedRelease
    from rosdeploy.images.supply import Supply

# rosdeploy.images.bundle and .supply are imported by the handlers: they bring paramiko, and
# every command (and TAB completion) builds this parser.


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "bundle", "write a release's images to one file, for sites without a registry",
                    "Resolve every image of the targeted robots' release to its digest and write the layers, "
                    "in an OCI image layout, with those digests into one tar file. `rosdeploy apply FLEET "
                    "--from-bundle FILE` then deploys it over SSH with no registry anywhere (docs/images.md).",
                    (EXIT_OK, EXIT_INPUT, EXIT_INTERNAL),
                    "rosdeploy bundle playbooks/demo.yml --version 1.1.0 --out demo-1.1.0.tar")
    add_fleet_args(p)
    p.add_argument("--out", required=True, type=path_arg, metavar="FILE",
                   help="the bundle to write (an OCI image layout in a tar)")
    p.set_defaults(func=cmd_bundle, acts=True)     # its product is the file (_after_lost_output)


def add_from_bundle(p: argparse.ArgumentParser) -> None:
    p.add_argument("--from-bundle", type=path_arg, metavar="FILE",
                   help="take the images from a `rosdeploy bundle` file, over SSH (no registry needed)")


def supply(args: argparse.Namespace, out: Output, spec: FleetSpec, hosts: Sequence[Host],
           releases: dict[str, RenderedRelease]) -> Supply | None:
    """Every image tag of the run resolved to its digest once, before any robot changes.
    None: the controller cannot read the registry and every robot pulls by itself; they
    then pull by tag, unpinned, as before (a site registry only robots can reach)."""
    from rosdeploy.images import bundle
    from rosdeploy.images.supply import VIA_VAR, check_vars, from_registry

    problems = check_vars(hosts)
    if problems:
        raise InputError([Problem("", None, "", problem) for problem in problems])
    targets = [releases[h.name] for h in hosts if h.name in releases]
    source = getattr(args, "from_bundle", None)
    if source:
        return bundle.from_bundle(spec, targets, Path(source))
    try:
        return from_registry(spec, targets)
    except InputError as exc:
        if any(host.vars.get(VIA_VAR, spec.images.via) == "ssh" for host in hosts):
            raise
        out.warn(f"warning: {exc.problems[0]}; images are not pinned by digest in this run "
                 "(robots pull by tag): set `images.controller_registry` to pin them")
        return None


def cmd_bundle(args: argparse.Namespace, out: Output) -> int:
    from rosdeploy.cli.remote import load
    from rosdeploy.images import bundle
    from rosdeploy.images.refs import human_bytes

    project, hosts, releases = load(args, out)
    target = Path(args.out)
    made = bundle.write(project.spec, [releases[h.name] for h in hosts], target)
    size = target.stat().st_size
    if out.as_json:
        out.document({"bundle": str(target), "bytes": size,
                      "images": {p.ref: {"digest": p.digest, "image_id": p.image_id} for p in made.pins.values()}})
        return EXIT_OK
    for pin in made.pins.values():
        out.line(f"{pin.ref}  {pin.digest}  ({human_bytes(pin.size)} compressed)")
    out.line(f"wrote {one_line(target)} ({human_bytes(size)})")
    return EXIT_OK
