"""The work budget of one command: what all its template renders may take together.

sandbox.MAX_WORK bounds one render, but a value costing 0.75 s rendered for each of 5,000 robots
took an hour. The CLI runs every command inside command_budget(); sandbox.metered() gives each
render at most what is left and takes back what it used. Kept apart from the sandbox, which
imports Jinja (70 ms): commands that render nothing (an emergency rollback) do not load it.
"""
from __future__ import annotations

import contextlib
import threading
from typing import Iterator

# About five seconds of template work (five times sandbox.MAX_WORK, a test holds them together).
# bench/validate_bench.py's 5,000 robots take next to none (their values read a var or two);
# 10,000 units a robot (a template file looping over 100 items and more) is far above what a
# fleet's values and files need.
COMMAND_WORK = 50_000_000


class _Command:
    left: list[int] | None = None    # [work left] to the renders of the command under way, or None: no bound


COMMAND = _Command()
LOCK = threading.Lock()     # inventories are templated in worker threads too


@contextlib.contextmanager
def command_budget(work: int | None = None) -> Iterator[None]:
    """Every render in this block (in any thread, and in the children forked.mapped forks in it,
    each with what was left at the fork) takes its work from one budget of `work` units
    (COMMAND_WORK unless given)."""
    outer = COMMAND.left
    COMMAND.left = [COMMAND_WORK if work is None else work]
    try:
        yield
    finally:
        COMMAND.left = outer
