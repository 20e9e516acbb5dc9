"""The variables rosdeploy reads, the Ansible ones it leaves alone, and the file kinds it knows."""
from __future__ import annotations

import re
import string
from typing import Iterable

from rosdeploy import suggest
from rosdeploy.errors import shown


# Real Ansible variables that merely look like the ones rosdeploy reads: never "did you mean".
ANSIBLE_VARS = frozenset({
    "ansible_become", "ansible_become_user", "ansible_become_pass", "ansible_become_password",
    "ansible_become_method", "ansible_become_exe", "ansible_become_flags", "ansible_connection",
    "ansible_password", "ansible_ssh_pass", "ansible_ssh_password", "ansible_python_interpreter",
    "ansible_shell_type", "ansible_shell_executable", "ansible_ssh_common_args", "ansible_ssh_extra_args",
    "ansible_sftp_extra_args", "ansible_scp_extra_args", "ansible_ssh_pipelining", "ansible_pipelining",
    "ansible_ssh_executable", "ansible_host_key_checking", "ansible_ssh_host_key_checking",
    "ansible_group_priority", "ansible_timeout", "ansible_ssh_timeout", "ansible_ssh_retries",
    "ansible_remote_tmp", "ansible_network_os", "ansible_hostname", "ansible_user_id", "ansible_user_dir",
    "ansible_user_shell", "ansible_docker_extra_args", "ansible_port_forwarding", "ansible_host_pattern",
})
NEAR_MISS_CUTOFF = 0.85

# Characters a shell, ssh or compose would give meaning to. Commands are quoted
# anyway; refusing them here is defence in depth and catches copy-paste junk.
SHELL_UNSAFE = frozenset(string.whitespace + "\0;&|$`'\"<>(){}[]*?!\\#~")
NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
SYMLINK = re.compile(r"[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*")
HEX4 = re.compile(r"[0-9a-fA-F]{4}")
SERIAL = re.compile(r"[A-Za-z0-9_.:/+-]+")
UNIX_GROUP = re.compile(r"[a-z_][a-z0-9_-]*")
SUBSYSTEM = re.compile(r"[a-z0-9_]+")
MODE = re.compile(r"0?[0-7]{3}")
UDEV_KEYS = ("symlink", "subsystem", "vendor", "product", "serial", "group", "mode")
UDEV_REQUIRED = ("symlink", "subsystem", "vendor", "product")
GROUP_KEYS = ("hosts", "vars", "children")
YAML_EXTS = (".yml", ".yaml", ".json")
VARS_EXTS = ("", *YAML_EXTS)
# Ansible's INVENTORY_IGNORE_EXTS: never read.
SKIPPED_EXTS = (".md", ".txt", ".rst", ".orig", ".bak", ".swp", ".pyc", ".pyo", ".retry", ".cfg", ".rpm", "~")
# Read as INI, as Ansible does, but skipped with a warning when that fails (Ansible's "Unable to parse").
MAYBE_NOT_INVENTORY = (".example", ".sample", ".j2")
# Dynamic inventories that are not executable: refused, not misread as INI (executable ones are run).
SCRIPT_EXTS = (".py", ".sh", ".js", ".rb", ".pl", ".ps1", ".exe")
TRUE = ("true", "yes", "on", "1", "y", "t")
FALSE = ("false", "no", "off", "0", "n", "f")


def did_you_mean_hint(word: object, choices: Iterable[str]) -> str:
    """`; did you mean 'x'?` to append to a message, or ""."""
    close = suggest.closest(word, choices, cutoff=0.6)
    return f"; did you mean {shown(close)}?" if close else ""
