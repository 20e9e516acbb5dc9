"""The local record of each run: result.json plus the logs of every failed service.

Kept under $ROSDEPLOY_RUNS_DIR (default ~/.rosdeploy/runs/<run id>/) so an
operator can read why robot7 rolled back after the terminal is gone.
"""
from __future__ import annotations

import json
import os
import secrets
import time
from pathlib import Path
from typing import Callable

from rosdeploy.output import masked_values
from rosdeploy.results import FleetResult


def new_run_id() -> str:
    return time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + secrets.token_hex(3)


def runs_dir() -> Path:
    return Path(os.environ.get("ROSDEPLOY_RUNS_DIR") or Path.home() / ".rosdeploy" / "runs")


def save(result: FleetResult, masked: Callable[[str], str]) -> Path:
    """Write the run's record; every text passes through `masked` so no secret lands on disk."""
    folder = runs_dir() / result.run_id
    folder.mkdir(parents=True, exist_ok=True)
    for host in result.hosts + result.fleet_rollback:
        for service, text in host.logs.items():
            (folder / f"{host.host}.{service}.log").write_text(masked(text) + "\n", encoding="utf-8")
    # the values masked before serializing: masking the JSON text missed a secret JSON escapes
    # (non-ASCII, a quote) and could break the record (a secret equal to `null` or a key)
    (folder / "result.json").write_text(json.dumps(masked_values(result.to_json(), masked), indent=2,
                                                   sort_keys=True) + "\n",
                                        encoding="utf-8")
    return folder
