"""keeper.py against OpenSSH's ControlPersist, for the read-only commands (issue #19).

    python bench/keeper_bench.py [--targets 10,100] [--runs 5] [--port 3101]

`status`, `plan` and `history` run one short command per robot. What differs between ways of
holding connections is the transport, so this measures exactly that, per N robots, N at once:
one `true` per target through

  paramiko, fresh      connect + run + close per target (status with `ssh.persist: 0`)
  keeper, held         rosdeploy.keeper's held paramiko connections (status today)
  ssh, fresh           one `ssh target true` process per target, no multiplexing
  ssh, ControlPersist  `ssh -o ControlMaster=auto -o ControlPersist=60 -o ControlPath=...`,
                       masters already up (what `status` over OpenSSH would do on a rerun)

against N sshd targets on loopback (bench/fleetbench/sshd.py; no simulated fleet needed).
Wall time median of --runs, and the controller's CPU (this process, its children and the
keeper; ControlPersist masters run detached and are not counted). Needs root (it adds the
`rdbench` user and starts sshd processes, all removed at the end). The keeper runs from a
private ROSDEPLOY_CONTROL_DIR, so no other keeper on the machine is touched.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fleetbench import sshd  # noqa: E402

Method = Callable[[Sequence[int]], None]


def cpu_now(keeper_pid: int | None) -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
    if keeper_pid:
        try:
            fields = Path(f"/proc/{keeper_pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except OSError:
            pass
    return total


class Bench:
    def __init__(self, work: Path, targets: Sequence[sshd.Target], key: Path, known_hosts: Path) -> None:
        from rosdeploy.model import Host
        from rosdeploy.transport import SSHOptions

        self.work, self.targets, self.key, self.known_hosts = work, targets, key, known_hosts
        self.options = SSHOptions(known_hosts=str(known_hosts), connect_timeout=30)
        self.hosts = [Host(name=t.name, groups=("all",), vars={}, address="127.0.0.1", port=t.port,
                           user=sshd.USER, key_file=str(key)) for t in targets]
        self.control = work / "cp"
        self.control.mkdir(mode=0o700)

    # ------------------------------------------------------------- rosdeploy
    def _threads(self, indexes: Sequence[int], one: Callable[[int], None]) -> None:
        with ThreadPoolExecutor(max_workers=len(indexes)) as pool:
            list(pool.map(one, indexes))

    def paramiko_fresh(self, indexes: Sequence[int]) -> None:
        from rosdeploy.transport import connect
        self._true_on(indexes, connect)

    def keeper_held(self, indexes: Sequence[int]) -> None:
        from rosdeploy.keeper import kept_connect
        self._true_on(indexes, kept_connect(60))

    def _true_on(self, indexes: Sequence[int], connect: Callable[..., Any]) -> None:
        """`true` on each target over a connection from `connect`, all at once (the two ways differ only there)."""
        from rosdeploy.commands import Command

        def one(i: int) -> None:
            transport = connect(self.hosts[i], self.options)
            try:
                assert transport.run(Command(("true",))).exited == 0
            finally:
                transport.close()
        self._threads(indexes, one)

    # --------------------------------------------------------------- OpenSSH
    def _ssh(self, i: int, mux: bool) -> list[str]:
        t = self.targets[i]
        argv = ["ssh", "-i", str(self.key), "-p", str(t.port), "-F", "/dev/null", "-o", "BatchMode=yes",
                "-o", "IdentitiesOnly=yes", "-o", f"UserKnownHostsFile={self.known_hosts}",
                "-o", "StrictHostKeyChecking=yes"]
        if mux:
            argv += ["-o", "ControlMaster=auto", "-o", "ControlPersist=60",
                     "-o", f"ControlPath={self.control}/%C"]
        return [*argv, f"{sshd.USER}@127.0.0.1", "true"]

    def _processes(self, indexes: Sequence[int], mux: bool) -> None:
        procs = [subprocess.Popen(self._ssh(i, mux), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE) for i in indexes]
        failed = [(p.args[-2], p.stderr.read().decode()[-200:]) for p in procs if p.wait(timeout=120) != 0]
        if failed:
            raise SystemExit(f"ssh failed: {failed[:3]}")

    def ssh_fresh(self, indexes: Sequence[int]) -> None:
        self._processes(indexes, mux=False)

    def ssh_persist(self, indexes: Sequence[int]) -> None:
        self._processes(indexes, mux=True)

    def close_masters(self) -> None:
        for i in range(len(self.targets)):
            subprocess.run([*self._ssh(i, True)[:-1], "-O", "exit"], capture_output=True, check=False)


def keeper_pid() -> int | None:
    from rosdeploy import keeper

    reply = keeper.ask({"op": "list"})
    return reply["pid"] if reply else None


def measure(bench: Bench, method: Method, indexes: Sequence[int], runs: int) -> tuple[float, float]:
    method(indexes)          # warm-up: starts the keeper / the masters for the held variants
    walls, cpus = [], []
    for _ in range(runs):
        pid = keeper_pid()
        cpu, started = cpu_now(pid), time.monotonic()
        method(indexes)
        walls.append(time.monotonic() - started)
        cpus.append(cpu_now(pid) - cpu)
    return statistics.median(walls), statistics.median(cpus)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--targets", default="10,100", help="comma-separated numbers of targets")
    p.add_argument("--runs", type=int, default=5, help="measured runs per method and N (median)")
    p.add_argument("--port", type=int, default=3101, help="first port of the sshd targets")
    args = p.parse_args(argv)
    sizes = sorted(int(n) for n in args.targets.split(","))
    work = Path(tempfile.mkdtemp(prefix="kb-", dir="/tmp"))     # short: ControlPath sockets live here
    work.chmod(0o755)
    os.environ["ROSDEPLOY_CONTROL_DIR"] = str(work / "keeper")
    # The keeper is a child process: it must import this checkout's rosdeploy too.
    repo = str(Path(__file__).resolve().parents[1])
    os.environ["PYTHONPATH"] = repo + os.pathsep + os.environ.get("PYTHONPATH", "")
    farm = None
    bench = None
    try:
        sshd.ensure_user(work / "home")
        targets = sshd.make_targets(work, max(sizes), args.port)
        key = sshd.keygen(work / "id_ed25519", "keeper-bench")
        known_hosts = sshd.write_known_hosts(work / "known_hosts", targets)
        farm = sshd.SshdFarm(work, targets, sshd.public_key(key))
        farm.start()
        bench = Bench(work, targets, key, known_hosts)
        methods = {"paramiko, fresh": bench.paramiko_fresh, "keeper, held": bench.keeper_held,
                   "ssh, fresh": bench.ssh_fresh, "ssh, ControlPersist": bench.ssh_persist}
        print("| targets | " + " | ".join(methods) + " |")
        print("|---:|" + "---:|" * len(methods))
        for n in sizes:
            cells = []
            for method in methods.values():
                wall, cpu = measure(bench, method, range(n), args.runs)
                cells.append(f"{wall:.2f} s (cpu {cpu:.2f} s)")
            print(f"| {n} | " + " | ".join(cells) + " |", flush=True)
    finally:
        from rosdeploy import keeper

        keeper.ask({"op": "exit"})
        if bench:
            bench.close_masters()
        if farm:
            farm.stop()
        sshd.remove_user()
        subprocess.run(["rm", "-rf", str(work)], check=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
