"""LeRobot's own robot classes, unchanged, against `climbsim serve --robot hil/robots/…`.

LeRobot 0.5.1 is installed without its heavy dependencies (requirements.txt); `stub/` puts a
stand-in for torch's one type alias on the path. Each test gets its own climbsim, stopped with
SIGTERM at teardown (exit 0 and the link removed, or the test fails).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent / "stub"))


def climbsim_bin() -> Path:
    path = Path(os.environ.get("CLIMBSIM_BIN", "target/debug/climbsim"))
    return path if path.is_absolute() else REPO_ROOT / path


class Served:
    """One `climbsim serve --robot DESCRIPTION` and the pty link it publishes."""

    def __init__(self, workdir: Path, robot: str):
        self.link = workdir / "ttyDXL"
        self.stdout_path, self.stderr_path = workdir / "stdout.log", workdir / "stderr.log"
        args = [str(climbsim_bin()), "serve", "--robot", str(REPO_ROOT / robot), "--link", str(self.link)]
        with open(self.stdout_path, "wb") as out, open(self.stderr_path, "wb") as err:
            self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=out, stderr=err, cwd=REPO_ROOT)
        deadline = time.monotonic() + 10
        while not any(line.startswith("port:") for line in self.stdout_path.read_text().split("\n")[:-1]):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                pytest.fail(f"climbsim serve did not publish its port: {self.diagnostics()}", pytrace=False)
            time.sleep(0.01)

    def diagnostics(self) -> str:
        return f"stdout:\n{self.stdout_path.read_text()}\nstderr:\n{self.stderr_path.read_text()[-4000:]}"

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            pytest.fail(f"climbsim did not end within 10 s of SIGTERM: {self.diagnostics()}", pytrace=False)
        assert code == 0, f"climbsim ended with {code} after SIGTERM: {self.diagnostics()}"
        assert not self.link.exists(), "climbsim left its link behind"


@pytest.fixture
def serve(tmp_path):
    """Factory: `serve("hil/robots/koch-follower.toml") -> Served`."""
    started: list[Served] = []

    def start(robot: str) -> Served:
        workdir = tmp_path / f"bus{len(started)}"
        workdir.mkdir()
        served = Served(workdir, robot)
        started.append(served)
        return served

    yield start
    for served in started:
        served.stop()
