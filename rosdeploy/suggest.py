"""The one did-you-mean rule every validator uses, so a typo gets the same hint everywhere."""
from __future__ import annotations

import difflib
from typing import Iterable

from rosdeploy.errors import shown

# One cutoff for every site: 0.75 catches a dropped, doubled or swapped letter in names of
# 6+ characters (ros_domian_id, rosdeploy_deploy_rot) without pairing unrelated short words.
CUTOFF = 0.75


def closest(word: object, choices: Iterable[str], cutoff: float = CUTOFF) -> str | None:
    """The choice nearest to `word`, or None when nothing is near enough to suggest."""
    close = difflib.get_close_matches(str(word), list(choices), n=1, cutoff=cutoff)
    return close[0] if close else None


def did_you_mean(word: object, choices: Iterable[str], cutoff: float = CUTOFF) -> str:
    """`did you mean 'x'?`, or "" when there is nothing to suggest."""
    near = closest(word, choices, cutoff)
    return f"did you mean {shown(near)}?" if near else ""
