"""SSHTransport setup without a network: what each robot's connection is built from."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from rosdeploy.model import Host
from rosdeploy.transport import SSHOptions, SSHTransport, parsed_ssh_config


def test_robot_threads_share_the_parsed_ssh_config_but_never_one_fabric_config(tmp_path: Path) -> None:
    known = tmp_path / "known_hosts"
    known.write_text("")
    options = SSHOptions(known_hosts=str(known))
    parsed = parsed_ssh_config(options)
    hosts = [Host(f"r{i}", ("all",), {}, "127.0.0.1", port=2200 + i, user="robot") for i in range(50)]
    with ThreadPoolExecutor(max_workers=16) as pool:
        transports = list(pool.map(lambda h: SSHTransport(h, options), hosts))
    configs = {id(t._conn.config) for t in transports}
    assert len(configs) == len(hosts)
    assert all(t._conn.config.base_ssh_config is parsed for t in transports)   # parsed once
    assert [t._conn.port for t in transports] == [h.port for h in hosts]
