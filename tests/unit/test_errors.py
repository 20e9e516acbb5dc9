"""How one problem reads: located where we know where, never an empty `: ` prefix."""
from __future__ import annotations

from rosdeploy.errors import InputError, Problem


def test_a_problem_reads_file_line_key_message() -> None:
    assert str(Problem("fleet.yml", 3, "services.x", "unknown key")) == "fleet.yml:3: services.x: unknown key"
    assert str(Problem("fleet.yml", None, "", "empty")) == "fleet.yml: empty"


def test_a_problem_without_a_file_has_no_empty_prefix() -> None:
    assert str(InputError("resolving image digests: registry down")) == "resolving image digests: registry down"
    assert str(Problem("", None, "images.via", "unknown")) == "images.via: unknown"
