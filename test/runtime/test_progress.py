"""Long work talks: `progress.Progress` on a terminal — a pseudo-terminal here, as a
user's — and nothing on a pipe; the tools that use it, run with stderr on a pty; each stops on
the first SIGINT. Every wait is on the text it means (a safety timeout only), never on time."""
import io
import os
import pty
import re
import select
import signal
import subprocess
import threading
from pathlib import Path

import pytest

from bag_rewrite import rewrite_bag
from executables import executable
from mobile_manip_sim.runtime.progress import Progress, duration_text
from waiting import TimedOut, wait_for

SAFETY = 120.0   # s: a safety net against a hang, not a measure


class Terminal:
    """A pseudo-terminal: `stream` writes to it (isatty() is True), `text()` is what came out."""

    def __init__(self):
        self.master, self.slave = pty.openpty()
        self.stream = open(self.slave, "w", closefd=False)
        self._seen = bytearray()
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._empty_looks = 0   # the reader's looks that found nothing to read
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        while not self._closing.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.1)
            if not ready:
                with self._lock:
                    self._empty_looks += 1
            else:
                try:
                    chunk = os.read(self.master, 4096)
                except OSError:   # the slave side closed
                    return
                if not chunk:
                    return
                with self._lock:
                    self._seen += chunk

    def text(self) -> str:
        with self._lock:
            return self._seen.decode(errors="replace")

    def _looks(self) -> int:
        with self._lock:
            return self._empty_looks

    def drain(self) -> None:
        """Once the writers are gone: wait until the reader has taken everything written (two
        empty looks from now: the second began after every write)."""
        looks = self._looks()
        wait_for(lambda: self._looks() >= looks + 2, "the reader to drain the terminal", SAFETY)

    def wait_for(self, pattern: str, what: str, process=None) -> re.Match:
        def seen():
            found = re.search(pattern, self.text())
            if found or process is None or process.poll() is None:
                return found
            self.drain()   # the process ended: what it wrote last is all there is
            found = re.search(pattern, self.text())
            assert found, f"{what}: the process ended ({process.returncode}):\n{self.text()}"
            return found

        try:
            return wait_for(seen, what, SAFETY)
        except TimedOut:
            raise AssertionError(f"no {what} in:\n{self.text()}") from None

    def close(self):
        # The reader stops before its descriptor is closed: the next terminal's pty may get the
        # same number, and a reader left running would take what was written there.
        self._closing.set()
        self._reader.join()
        self.stream.close()
        os.close(self.slave)
        os.close(self.master)


@pytest.fixture
def terminal():
    tty = Terminal()
    yield tty
    tty.close()


def test_nothing_is_written_to_a_pipe():
    stream = io.StringIO()
    progress = Progress("work", 10, "s", stream=stream)
    progress.follow(lambda: 5.0)
    progress.update(3.0)
    progress.close()
    assert not progress.active and stream.getvalue() == ""


def test_on_a_terminal_the_line_follows_work_inside_one_long_call(terminal):
    """No `update` at all: the ticker reads `follow()` and writes done, share, rate, time to go."""
    progress = Progress("work", 10, "s", rate_unit="s per wall s", stream=terminal.stream)
    progress.follow(lambda: 3.0)
    found = terminal.wait_for(r"work: 3 of 10 s \(30 %\), (\S+) s per wall s, (.+?) to go",
                              "a status line")
    assert float(found[1]) > 0 and found[2] != "?"
    progress.update(10.0)
    progress.close()
    terminal.wait_for(r"work: 10 of 10 s \(100 %\), \S+ s per wall s, 0 s to go\r?\n",
                      "the final status line")
    assert "\r\x1b[K" in terminal.text()   # rewritten in place


def test_a_status_line_and_a_phase_talk_at_once(terminal):
    """Written in the constructor, before the ticker's first look (1 s): a phase is "(0 s)"
    only then; counted work starts at 0 %, never at 100 %."""
    phase = Progress("sweep", None, "starting a LocalCluster of 2 workers",
                     stream=terminal.stream)
    work = Progress("work", 10, "s", stream=terminal.stream)
    terminal.drain()
    text = terminal.text()
    phase.close()
    work.close()
    assert "sweep: starting a LocalCluster of 2 workers (0 s)" in text, text
    assert "work: 0 of 10 s (0 %), 0 s/s, ? to go" in text, text


@pytest.mark.parametrize("seconds, text", [(0.4, "0 s"), (42, "42 s"), (200, "3 min 20 s"),
                                           (24_000, "6 h 40 min"), (float("inf"), "?")])
def test_durations_read_as_people_read_them(seconds, text):
    assert duration_text(seconds) == text


# --- the tools, with stderr on a pseudo-terminal -----------------------------------------------

def started(terminal, *command, cwd=None):
    return subprocess.Popen(list(command), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=terminal.slave, cwd=cwd)


def after_one_sigint(process, terminal) -> tuple[int, str]:
    """Send one SIGINT to a running process; its exit status and what the terminal shows."""
    assert process.poll() is None, terminal.text()
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=SAFETY)
    return process.returncode, terminal.text()


def test_simulate_shows_its_progress_on_a_terminal_and_stops_on_sigint(terminal, tmp_path):
    process = started(terminal, executable("simulate"), "--method", "dop853", "--duration", "1e5",
                      "--sample-rate", "1", "--out", str(tmp_path / "run.csv"))
    terminal.wait_for(r"simulate: \S+ of 100000 s \(\d+ %\), \S+ s per wall s, .+ to go",
                      "simulate's status line", process)
    status, text = after_one_sigint(process, terminal)
    assert status == 130 and "Traceback" not in text, text   # stopped at once, no traceback


def test_a_finished_simulate_ends_its_status_line_at_100_percent(terminal, tmp_path):
    process = started(terminal, executable("simulate"), "--duration", "0.5",
                      "--out", str(tmp_path / "run.csv"))
    stdout, _ = process.communicate(timeout=SAFETY)
    assert process.returncode == 0, terminal.text()
    terminal.wait_for(r"simulate: 0\.5 of 0\.5 s \(100 %\), .+ to go\r?\n", "the last status line")
    assert stdout.decode().startswith("simulated 0.5 s")   # stdout holds the summary alone


def slow_bag(tmp_path: Path, sample_rate: str) -> Path:
    """A 5 s bag sampled at `sample_rate` Hz whose re-run is slow (its method rewritten to radau
    at rtol 1e-14)."""
    recorded, slow = tmp_path / "bag", tmp_path / "slow"
    result = subprocess.run([executable("simulate"), "--method", "dop853", "--duration", "5",
                             "--sample-rate", sample_rate, "--out", str(tmp_path / "run.csv"),
                             "--record", str(recorded)], capture_output=True, timeout=SAFETY)
    assert result.returncode == 0, result.stderr
    from mobile_manip_sim.recording.bag_reader import open_bag
    metadata = dict(open_bag(recorded).metadata()["mobile_manip_sim"])
    metadata.update(integrator_method="radau", rtol="1e-14", atol="1e-20")
    rewrite_bag(recorded, slow, metadata={"mobile_manip_sim": metadata})
    return slow


def test_replay_resimulate_shows_its_progress_and_stops_on_sigint(terminal, tmp_path):
    """A bag whose re-run is slow (its method rewritten to radau at rtol 1e-14)."""
    process = started(terminal, executable("replay"), str(slow_bag(tmp_path, "100")),
                      "--resimulate")
    terminal.wait_for(r"replay --resimulate: \S+ of 5(\.0+)? s of the bag \(\d+ %\), "
                      r"\S+ bag s per wall s, .+ to go", "the re-simulation's status line", process)
    status, text = after_one_sigint(process, terminal)
    assert status == 130 and "Traceback" not in text, text   # stopped at once, no traceback


def test_sweep_talks_in_every_phase_and_counts_from_what_is_done(terminal, tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text("duration: 0.2\ngrid:\n  initial.velocity[2]: [0.0, 0.1, 0.2, 0.3]\n")
    process = started(terminal, executable("sweep"), str(spec), "--out", str(tmp_path / "out"),
                      "--workers", "1")
    for pattern in (rf"sweep: expanding the spec and reading {tmp_path}/out \(\d+ s\)",
                    r"sweep: starting a LocalCluster of 1 worker \(\d+ s\)",
                    r"sweep: the workers get ready \(",
                    r"sweep: 0 of 4 runs \(0 %\), 0 runs/s, \? to go"):
        terminal.wait_for(pattern, f"the line {pattern!r}", process)
    process.communicate(timeout=SAFETY)
    assert process.returncode == 0, terminal.text()
    text = terminal.text()
    assert text.index("sweep: 0 of 4 runs") < text.index("sweep: 4 of 4 runs (100 %)"), text
    assert "Traceback" not in text, text


def test_replay_resimulate_counts_what_is_simulated_not_what_is_read(terminal, tmp_path):
    """Two samples, t = 0 and t = 5 s, and a slow method: while the one long segment is
    computed the line says 0 %, never 100 % (it said so from the first second)."""
    process = started(terminal, executable("replay"), str(slow_bag(tmp_path, "0.2")),
                      "--resimulate")
    # the line when made, then two of the ticker's (one a second) while the segment computes
    wait_for(lambda: terminal.text().count("replay --resimulate: ") >= 3 or process.poll(),
             "three status lines", SAFETY)
    text = terminal.text()
    status, _ = after_one_sigint(process, terminal)
    assert status == 130, text
    assert "replay --resimulate: 0 of 5 s of the bag (0 %)" in text, text
    assert "100 %" not in text, text


def test_bench_talks_on_a_terminal_and_stops_on_sigint(terminal, tmp_path):
    process = started(terminal, executable("bench"), "--out", str(tmp_path), "--quick")
    terminal.wait_for(r"\[1/\d+\] ", "bench's first section", process)
    status, text = after_one_sigint(process, terminal)
    assert status == 130 and "Traceback" not in text, text   # stopped at once, no traceback


def test_bootstrap_says_still_while_a_silent_command_runs():
    """tools/talking.sh's `talking`, as tools/bootstrap.sh uses it (bootstrap itself is not run
    here: it would reinstall the venv): a line every 10 s while the command is silent, and the
    command's status kept."""
    tools = Path(__file__).resolve().parents[2] / "tools"
    command = f'. {tools / "talking.sh"}; TALKING_AS=bootstrap\n' \
              f'talking "waiting" bash -c "sleep 11; exit 3"'
    result = subprocess.run(["bash", "-c", command], capture_output=True, text=True,
                            timeout=SAFETY)
    assert result.returncode == 3 and result.stdout == "bootstrap: still waiting (10 s)\n"
    text = (tools / "bootstrap.sh").read_text()
    for phase in ("upgrading pip", "installing the package", "building tf2_msgs and control_msgs"):
        assert f'echo "bootstrap: {phase}' in text   # a line before each phase


def test_sweep_shows_runs_done_failed_and_time_to_go_on_a_terminal(terminal, tmp_path):
    spec = Path(__file__).resolve().parents[2] / "config" / "sweeps" / "paper_mass_and_method.yaml"
    process = started(terminal, executable("sweep"), str(spec), "--out", str(tmp_path / "out"),
                      "--workers", "1")
    process.communicate(timeout=600)
    assert process.returncode == 0, terminal.text()
    terminal.wait_for(r"sweep: 16 of 16 runs \(100 %\), \S+ runs/s, .+ to go, 0 failed\r?\n",
                      "sweep's last status line")
