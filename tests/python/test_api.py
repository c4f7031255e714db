"""climbsim's Python API and pytest plugin, as installed from the wheel (scripts/test-outside.sh
runs this in a fresh venv, outside the checkout): each call starts the real binary."""

import json
import os
import shutil
import subprocess
import sys
import time
import tomllib
import urllib.error
import urllib.request
from pathlib import Path

import pytest

import climbsim

pytest_plugins = ["pytester"]

SHORT = {"world.duration_s": 2.0}


@pytest.fixture
def follower(tmp_path):
    """The reference controller and a scenario that runs it, written out by the binary."""
    subprocess.run([climbsim.find_binary(), "init", str(tmp_path / "repo")], check=True, capture_output=True)
    return tmp_path / "repo"


def test_the_binary_is_the_one_installed_beside_the_package():
    binary = Path(climbsim.find_binary())
    assert binary.parent == Path(sys.executable).parent, binary
    version = subprocess.run([sys.executable, "-m", "climbsim", "--version"], check=True, capture_output=True, text=True).stdout
    assert version.startswith("climbsim "), version


def test_toml_values_are_what_toml_reads_back():
    value = {"a b": [1, 2.5, True, "x\"y\\z\n", "ü😀"], "n": {"k": -3}}
    assert tomllib.loads(f"v = {climbsim.toml_value(value)}")["v"] == value
    assert tomllib.loads(f"v = {climbsim.toml_value(float('inf'))}")["v"] == float("inf")
    with pytest.raises(TypeError):
        climbsim.toml_value(object())


def test_serve_on_the_bench_and_in_a_world(follower):
    with climbsim.serve() as bus:
        assert os.path.exists(bus.port) and bus.sensors is None
    assert bus.process.returncode in (0, 130)
    link = follower / "ttyDXL"
    with climbsim.serve(follower / "scenarios/line-follow.toml", link=link, sets={"world.seed": 3}) as bus:
        assert bus.port == str(link) and link.exists()
        line = first_line_measurement(bus.sensors)
        assert {"t", "d", "psi", "valid"} <= set(line), line
    assert not link.exists(), "the link is removed when climbsim ends"


def first_line_measurement(sensors, within_s=30.0):
    """GET /line until the world has a camera frame: before the first, the sensor server
    answers 503 (not yet), as it documents."""
    deadline = time.monotonic() + within_s
    while True:
        try:
            with urllib.request.urlopen(f"{sensors}/line", timeout=5) as answer:
                return json.load(answer)
        except urllib.error.HTTPError as error:
            if error.code != 503 or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_serve_that_cannot_start_raises_climbsims_own_message(follower):
    with pytest.raises(climbsim.ClimbsimError) as error:
        with climbsim.serve(follower / "scenarios/line-follow.toml", sets={"world.frobnicate": 1}):
            pytest.fail("served a bad scenario")
    assert error.value.message.startswith("climbsim: ") and "frobnicate" in error.value.message, error.value.message
    assert error.value.exit_code == 2


def test_run_with_another_controller_returns_its_summary_and_folder(follower, tmp_path, monkeypatch):
    monkeypatch.chdir(follower)
    result = climbsim.run(
        "scenarios/line-follow.toml",
        controller=["./controller/line_follower.py", "--zeta", "0.7"],
        sets={**SHORT, "expect": {"controller.period_p50_ms": {"max": 22.0}}},
        out=tmp_path / "run",
    )
    assert result.passed, result.failures
    assert result.out == tmp_path / "run" and (result.out / "timeseries.csv").is_file()
    assert result.summary["clock"] == "virtual" and result.summary["controller.period_p50_ms"] < 22.0
    settings = json.loads((result.out / "settings.json").read_text())
    assert "--zeta" in json.dumps(settings) and "0.7" in json.dumps(settings)


def test_a_failed_check_is_a_result_with_climbsims_lines(follower, tmp_path):
    result = climbsim.check(follower / "scenarios/line-follow.toml", sets=SHORT, out=tmp_path / "check")
    assert not result.passed and result.exit_code == 1
    assert any(line.startswith("distance.steady_state_error_m = ") for line in result.failures.lines), result.failures
    assert result.failures == "\n".join(result.summary["failures"])
    assert result.out == tmp_path / "check" / "line-follow" and (result.out / "summary.json").is_file()


def test_bad_input_to_run_raises(follower, tmp_path):
    with pytest.raises(climbsim.ClimbsimError) as error:
        climbsim.run(follower / "scenarios/line-follow.toml", sets={"world.duration_s": -3}, out=tmp_path / "bad")
    assert "world.duration_s: -3 s is outside" in str(error.value)
    with pytest.raises(climbsim.ClimbsimError) as error:
        climbsim.check(tmp_path / "missing.toml", out=tmp_path / "bad")
    assert "missing.toml" in str(error.value)


def test_the_plugins_failures_show_climbsims_lines(pytester, follower, monkeypatch):
    # climbsim's own log on its stderr (a line as its port is ready), for the report below.
    monkeypatch.setenv("RUST_LOG", "climbsim=info")
    shutil.copytree(follower / "scenarios", pytester.path / "scenarios")
    shutil.copytree(follower / "controller", pytester.path / "controller")
    pytester.makeini("[pytest]\nclimbsim_scenarios = scenarios\n")
    pytester.makepyfile(
        """
        import pytest

        def test_short(climbsim_check):
            result = climbsim_check("line-follow.toml", sets={"world.duration_s": 2.0})
            assert result.passed, result.failures

        @pytest.mark.climbsim_scenario("line-follow.toml")
        def test_bus(climbsim_bus):
            assert climbsim_bus.sensors.startswith("http://127.0.0.1:")

        @pytest.mark.climbsim_scenario("line-follow.toml")
        def test_bus_body_fails(climbsim_bus):
            assert climbsim_bus.port == "not this port"
        """
    )
    outcome = pytester.runpytest_subprocess()
    outcome.assert_outcomes(passed=1, failed=2)
    outcome.stdout.fnmatch_lines(["*AssertionError: distance.steady_state_error_m = * is outside*", "*time_on_line_fraction = 0 is outside >= 0.5*"])
    assert "climbsim: " in "\n".join(outcome.outlines), "the report header names the binary"
    # A test body that fails while the bus is up: climbsim's own lines and stderr in its report,
    # under the failure, and only there.
    outcome.stdout.fnmatch_lines(["*_ test_bus_body_fails _*", "*climbsim serve (its lines and stderr)*", "port: *", "sensors: http://127.0.0.1:*", "--- stderr ---", "*INFO climbsim::transport::pty: virtual serial port ready*"])
    assert "\n".join(outcome.outlines).count("climbsim serve (its lines and stderr)") == 1, "the passing and the short test have none"
