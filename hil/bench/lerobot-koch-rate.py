"""LeRobot's Koch follower loop on the wall clock: rounds of `get_observation()` + `send_action()`
(one Sync Read and one Sync Write of six servos at 1 Mbps) per second, through a real pty against
`climbsim serve --robot hil/robots/koch-follower.toml`. Run with LeRobot's venv:

    .venv-lerobot/bin/python hil/bench/lerobot-koch-rate.py [CLIMBSIM] [SECONDS] [RUNS]

Prints each run's rate and their median; the machine should be otherwise idle.
"""

from __future__ import annotations

import builtins
import json
import pathlib
import signal
import statistics
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "lerobot" / "stub"))
sys.path.insert(0, str(REPO / "tests" / "lerobot"))

from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig  # noqa: E402
from test_koch_follower import CALIBRATION  # noqa: E402

climbsim = sys.argv[1] if len(sys.argv) > 1 else str(REPO / "target/release/climbsim")
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 5.0
runs = int(sys.argv[3]) if len(sys.argv) > 3 else 5

rates = []
for run in range(runs):
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        link = tmp / "ttyDXL"
        server = subprocess.Popen([climbsim, "serve", "--robot", str(REPO / "hil/robots/koch-follower.toml"), "--link", str(link)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            assert server.stdout.readline().startswith("port:"), "climbsim did not publish its port"
            (tmp / "calibration").mkdir()
            (tmp / "calibration" / "bench.json").write_text(json.dumps(CALIBRATION))
            robot = KochFollower(KochFollowerConfig(port=str(link), id="bench", calibration_dir=tmp / "calibration"))
            builtins.input = lambda prompt="": ""
            robot.connect(calibrate=True)
            action = {f"{motor}.pos": 0.0 for motor in CALIBRATION}
            rounds, started = 0, time.perf_counter()
            while time.perf_counter() - started < seconds:
                robot.get_observation()
                robot.send_action(action)
                rounds += 1
            rate = rounds / (time.perf_counter() - started)
            robot.disconnect()
        finally:
            server.send_signal(signal.SIGTERM)
            try:
                code = server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.kill()
                code = server.wait()
        if code != 0:
            sys.exit(f"climbsim ended with {code}")
        rates.append(rate)
        print(f"run {run + 1}: {rate:.0f} rounds/s ({rounds} in {seconds:.0f} s)")
print(f"median {statistics.median(rates):.0f} rounds/s over {runs} runs of {seconds:.0f} s (min {min(rates):.0f}, max {max(rates):.0f})")
