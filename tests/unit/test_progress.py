"""The progress view: the live board on a terminal, lines elsewhere, and the output layer's
live region that keeps other text above the board."""
from __future__ import annotations

import io

from rosdeploy.cli import report
from rosdeploy.output import Output


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def board(hosts: list[str], height: int = 40) -> tuple[report.Board, Output]:
    out = Output(stdout=Terminal(), stderr=Terminal(), color=False)
    return report.Board(out, hosts, started=0.0, height=height), out


def test_board_rows_show_wave_step_and_elapsed_per_robot() -> None:
    b, _ = board(["robot1", "robot2", "robot3"])
    b.wave(1, ["robot1"])
    b.wave(2, ["robot2", "robot3"])
    b.rows["robot1"] = report.Row(wave=1, step="deployed", since=1.0, done=4.5)
    b.progress("robot2", "pull")
    b.rows["robot2"].since = 2.0
    lines = b.lines(now=5.0)
    assert lines[0].split() == ["ROBOT", "WAVE", "STEP", "ELAPSED"]
    assert lines[1].split() == ["robot1", "1", "deployed", "3.5s"]
    assert lines[2].split() == ["robot2", "2", "pull", "3.0s"]
    assert lines[3].split() == ["robot3", "2", "waiting"]
    assert lines[4] == "5.0s: 1 running, 1 done (0 not ok), 1 waiting"


def test_an_outcome_ends_a_robot_and_a_second_run_starts_it_again() -> None:
    b, _ = board(["robot1"])
    b.progress("robot1", "connect")
    b.progress("robot1", "rolled-back")
    assert b.rows["robot1"].done is not None
    b.progress("robot1", "connect")          # fleet-level rollback: the robot runs again
    assert b.rows["robot1"].running and b.rows["robot1"].step == "connect"


def test_a_fleet_larger_than_the_terminal_shows_running_and_failed_first() -> None:
    hosts = [f"r{i:03d}" for i in range(100)]
    b, _ = board(hosts, height=12)
    for h in hosts[:60]:
        b.rows[h] = report.Row(since=0.0, done=1.0, step="deployed")
    b.rows["r010"].step = "failed"
    for h in hosts[90:]:
        b.rows[h] = report.Row(since=0.5, step="health")
    lines = b.lines(now=2.0)
    shown = [line.split()[0] for line in lines[1:-1]]
    assert len(lines) <= 12 and len(shown) == 8
    assert shown[:1] == ["r010"] and set(shown[1:]) <= set(hosts[90:])   # failed, then running
    assert lines[-1] == "2.0s: 10 running, 60 done (1 not ok), 30 waiting  (92 more not shown)"


def test_text_printed_during_a_live_region_lands_above_it() -> None:
    out = Output(stdout=Terminal(), stderr=Terminal(), color=False)
    out.live(["ROBOT  STEP", "robot1 pull"])
    out.line("== wave 2/2: robot2")
    out.live([])
    text = out.stdout.getvalue()
    erase = "\033[2F\033[J"
    assert text == "ROBOT  STEP\nrobot1 pull\n" + erase + "== wave 2/2: robot2\n" + "ROBOT  STEP\nrobot1 pull\n" + erase


def test_without_a_terminal_progress_is_plain_lines() -> None:
    out = Output(stdout=io.StringIO(), stderr=io.StringIO(), color=False)
    with report.progress_view(out, ["robot1"]) as view:
        view.progress("robot1", "connect")
        view.progress("robot1", "deployed")
    lines = out.stdout.getvalue().splitlines()
    assert [line.split()[1:] for line in lines] == [["robot1", "connect"], ["robot1", "deployed"]]
    assert "\033" not in out.stdout.getvalue()


def test_the_board_is_erased_before_the_summary() -> None:
    out = Output(stdout=Terminal(), stderr=Terminal(), color=False)
    with report.progress_view(out, ["robot1"]) as view:
        assert isinstance(view, report.Board)
        view.progress("robot1", "connect")
    assert out._live == [] and out.stdout.getvalue().endswith("\033[J")


def test_the_summary_shows_an_unchanged_robots_reason_only_when_host_changes_were_put_back() -> None:
    from rosdeploy.results import HostResult, Step
    plain = HostResult("r1", "unchanged", "1.0.0-a", "1.0.0-a", "1.0.0-a", reason="already on this release and healthy",
                       steps=(Step("connect", 0.1), Step("check", 0.1)))
    put_back = HostResult("r2", "unchanged", "1.0.0-a", "1.0.0-a", "1.0.0-a",
                          reason="already on this release and healthy; put back its host changes, which differed "
                                 "on the robot: /etc/cron.d/rosdeploy-demo",
                          steps=(Step("check", 0.1), Step("lock", 0.1), Step("host changes", 0.2, detail="installed")))
    deployed = HostResult("r3", "deployed", None, "1.0.0-a", "1.0.0-a", reason="healthy",
                          steps=(Step("host changes", 0.2, detail="installed"),))
    assert report._row(plain)[-1] == "" and report._row(deployed)[-1] == ""
    assert report._row(put_back)[-1].endswith("/etc/cron.d/rosdeploy-demo")
