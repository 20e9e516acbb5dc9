"""Arguments shared by several commands, so they read the same everywhere."""
from __future__ import annotations

import argparse


def add_fleet_args(parser: argparse.ArgumentParser, *, limit: bool = True, version: bool = True) -> None:
    parser.add_argument("fleet", metavar="FLEET", help="the fleet file, e.g. playbooks/warehouse.yml")
    parser.add_argument("-i", "--inventory", metavar="PATH",
                        help="inventory file or directory (overrides the fleet file's `inventory`)")
    if limit:
        parser.add_argument("-l", "--limit", metavar="PATTERN",
                            help="robots to target, Ansible patterns: names, groups, globs, a:b, a:&b, a:!b")
    if version:
        parser.add_argument("--version", dest="release_version", metavar="V",
                            help="release version (every image's tag; overrides the fleet file's `version`)")
    parser.add_argument("--vault-password-file", metavar="FILE",
                        help="file holding the vault password (or set ROSDEPLOY_VAULT_PASSWORD[_FILE])")
