"""The compatibility suite's figures, printed at the end of every run that collected it."""
from __future__ import annotations

import pytest

from compat import FIGURES


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    inventories, patterns = FIGURES["inventories"], FIGURES["patterns"]
    if inventories[1] or patterns[1]:
        terminalreporter.write_line(
            f"ansible compat: {inventories[0]} of {inventories[1]} real inventories load with the same hosts, "
            f"groups and vars as Ansible; {patterns[0]} of {patterns[1]} patterns select the same hosts")
