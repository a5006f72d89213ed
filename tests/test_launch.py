"""Launch files: parsing and validation, process supervision, and a threaded fleet run."""

from __future__ import annotations

import itertools
import json
import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest
from unit_frames import two_units

from atris_node.cli import main
from atris_node.codes import code_set
from atris_node.errors import ConfigError
from atris_node.node.launch import describe, load_launch
from atris_node.node.runner import ProcessRun, escalate, unit_command


@pytest.mark.parametrize("name", ["sim_fleet", "sim_soak", "vcan_pair", "oak_vehicle"])
def test_shipped_launch_files_load(name: str) -> None:
    spec = load_launch(name)
    assert spec.units and len({u["unit.unit_id"] for u in spec.units}) == len(spec.units)
    lines = describe(spec)
    assert len(lines) == 1 + len(spec.units)


def test_print_shows_units_and_changed_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["launch", "sim_fleet", "--print"]) == 0
    out = capsys.readouterr().out
    assert "3 unit(s) as threads" in out
    assert "unit centre:" in out and "driver.scene='fleet'" in out


@pytest.mark.parametrize(("text", "message"), [
    ("[launch]\nname='x'\n", "at least one"),
    ("[lanch]\n[[unit]]\n", "unknown key"),
    ("[[unit]]\nunit = { unit_id = 1 }\n[[unit]]\nunit = { unit_id = 1, label = 'b' }\n",
     "share a unit_id"),
    ("[[unit]]\ncode = { length = 12 }\n", "power of two"),
    ("[launch]\nmode = 'fork'\n[[unit]]\n", "threads or processes"),
])
def test_bad_launch_files_are_clear_errors(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_launch(path)


def _sleeper(ignore: tuple[str, ...]) -> subprocess.Popen[bytes]:
    """A Python child that sleeps; it obeys SIGINT (even when started from a shell that
    ignores SIGINT for background jobs, which the child would inherit) unless told to
    ignore it."""
    handlers = "signal.signal(signal.SIGINT, signal.default_int_handler);" + "".join(
        f"signal.signal(signal.{s}, signal.SIG_IGN);" for s in ignore)
    code = f"import signal, time, sys; {handlers} print('up', flush=True); time.sleep(60)"
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert process.stdout is not None and process.stdout.readline() == b"up\n"
    return process


def test_escalation_stops_at_sigint_when_obeyed() -> None:
    """A process that obeys SIGINT ends by it, however long a loaded machine takes to
    let it exit (the wait for it is generous; no SIGTERM follows)."""
    process = _sleeper(())
    assert escalate(process, waits=(30.0, 2.0)) == -signal.SIGINT


def test_escalation_goes_to_sigkill_when_ignored() -> None:
    process = _sleeper(("SIGINT", "SIGTERM"))
    assert escalate(process, waits=(0.2, 0.2)) == -signal.SIGKILL


def test_respawn_policy_limits_restarts_with_back_off(tmp_path: Path) -> None:
    """Respawns wait 0.5 s, then 1 s (doubling); after the last allowed one the unit stays
    down and is named failed. Checked by respawning at once (no back-off, as before): the
    respawns came one supervision step (0.05 s) apart and the delay assert failed."""
    path = tmp_path / "procs.toml"
    path.write_text("[launch]\nmode='processes'\nrespawn=true\nmax_respawns=2\n"
                    "[[unit]]\nunit={label='x'}\n")
    spec = load_launch(path)
    started: list[tuple[float, list[str]]] = []
    now = [0.0]

    def spawn(command: list[str]) -> subprocess.Popen[bytes]:
        started.append((now[0], command))
        process = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
        process.wait()
        return process

    run = ProcessRun(spec, spawn=spawn)
    run.start()
    while now[0] < 10.0:
        run.supervise(now[0])
        now[0] += 0.05
    run.stop()
    assert len(started) == 3 and run.children[0].respawns == 2
    delays = [b[0] - a[0] for a, b in itertools.pairwise(started)]
    assert delays == pytest.approx([0.5, 1.0], abs=0.06)
    assert run.failed == ["x"] and run.children[0].gave_up == 3
    assert started[0][1] == unit_command(spec.units[0])
    assert "unit.label=x" in started[0][1]


def test_launch_exits_1_when_a_unit_stays_down(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A unit process that cannot start (its scene does not exist) and is not respawned
    makes ``atris launch`` exit 1 and names it. Checked by returning 0 regardless (as
    before): the exit-code assert failed."""
    path = tmp_path / "broken.toml"
    path.write_text("[launch]\nmode='processes'\n"
                    "[[unit]]\nunit={label='broken'}\n"
                    f"driver={{scene='{tmp_path / 'missing.toml'}'}}\n"
                    "bus={interface='virtual', channel='launch-broken'}\n")
    # the launch ends when every unit stays down; the duration is only an upper bound
    assert main(["launch", str(path), "--duration", "120", "--json", "--quiet"]) == 1
    summary = json.loads(capsys.readouterr().out)
    assert summary["failed"] == ["broken"]


def test_threaded_pair_negotiates_and_logs_every_frame(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str],
                                                        request: pytest.FixtureRequest) -> None:
    path = tmp_path / "pair.toml"
    path.write_text(two_units(f"launch-{request.node.name}", duration_s=3.0))
    log = tmp_path / "bus.log"
    assert main(["launch", str(path), "--duration", "4", "--json", "--log", str(log),
                 "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    units = summary["units"]
    assert [u["name"] for u in units] == ["a", "b"]
    assert all(set(u) >= {"name", "code_row", "code_length", "state", "frames_sent",
                          "e2e_errors"} for u in units)
    rows = [u["code_row"] for u in units]
    assert len(set(rows)) == 2 and set(rows) <= set(code_set(8, "async"))
    assert all(u["state"] == "RUNNING" and u["code_length"] == 8 for u in units)
    assert all(u["frames_sent"] > 20 and u["e2e_errors"] == 0 for u in units)
    logged = list(can.LogReader(str(log)))
    assert len(logged) >= sum(u["frames_sent"] for u in units)
