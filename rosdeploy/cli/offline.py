"""Subcommands of this area; see rosdeploy/cli/__init__.py."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    pass
