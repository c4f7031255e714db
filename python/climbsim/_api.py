"""climbsim from Python: a served bus for a test, a run, a check. Each call starts the binary
(`find_binary`) with the same flags the command line takes, so everything docs/ says of
`climbsim serve`, `run` and `check` holds here."""

from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

from ._binary import find_binary
from ._errors import ClimbsimError

PathLike = Union[str, "os.PathLike[str]"]
Value = Union[bool, int, float, str, Sequence[Any], Mapping[str, Any]]

# climbsim's exit codes (docs/exit-codes.md).
EXIT_PASSED = 0
EXIT_FAILED = 1


def toml_value(value: Value) -> str:
    """`value` written as TOML, as `--set KEY=VALUE` takes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        # A JSON string is a TOML basic string once non-ASCII characters are left as they are
        # (JSON would write an emoji as a surrogate pair, which TOML refuses).
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{json.dumps(str(k), ensure_ascii=False)} = {toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, os.PathLike):
        return toml_value(os.fspath(value))
    raise TypeError(f"cannot write {value!r} ({type(value).__name__}) as a TOML value")


def _flags(sets: Optional[Mapping[str, Value]], controller: Optional[Sequence[PathLike]], robot: Optional[PathLike], args: Sequence[str]) -> List[str]:
    """The flags every call shares: `--set` for `sets` (and `controller`), `--robot`, then
    `args` as given."""
    flags: List[str] = []
    for key, value in (sets or {}).items():
        flags += ["--set", f"{key}={toml_value(value)}"]
    if controller is not None:
        flags += ["--set", f"controller={toml_value({'kind': 'external', 'command': _controller_command(controller)})}"]
    if robot is not None:
        flags += ["--robot", os.fspath(robot)]
    return flags + list(args)


def _environment(env: Optional[Mapping[str, str]]) -> Optional[Dict[str, str]]:
    """climbsim's environment: this process's with `env` on top (None: this process's)."""
    return None if env is None else {**os.environ, **env}


def _controller_command(controller: Sequence[PathLike]) -> List[str]:
    """The controller's command with `./` and `../` arguments made absolute from the current
    folder (the Python caller's), since climbsim resolves a scenario's from the scenario's."""
    if isinstance(controller, (str, os.PathLike)):
        raise TypeError("controller= is a command: a list of program and arguments, e.g. ['python3', 'follower.py']")
    command = []
    for part in controller:
        text = os.fspath(part)
        if text.startswith(("./", "../")):
            text = os.path.abspath(text)
        command.append(text)
    return command


def _climbsim_lines(errors: str) -> str:
    """climbsim's own error lines from its stderr (the `climbsim: …` line and what follows it),
    or all of it when there is none."""
    lines = errors.splitlines()
    for index, line in enumerate(lines):
        if line.startswith("climbsim: "):
            return "\n".join(lines[index:])
    return errors.strip() or "(climbsim printed no error)"


class Failures(str):
    """What failed: climbsim's lines, one per line, as it prints them ("" when nothing failed).
    A string, so that `assert result.passed, result.failures` shows them whole (pytest shortens
    the repr of anything else); `.lines` has them one by one."""

    @property
    def lines(self) -> List[str]:
        return self.splitlines()


@dataclass
class RunResult:
    """How a run or a check ended. `passed` is climbsim's verdict (exit code 0): its `[expect]`
    thresholds held and the controller and the world ran to the end."""

    passed: bool
    exit_code: int
    #: climbsim's summary.json: every metric, the failures, the controller's exit.
    summary: Dict[str, Any]
    failures: Failures
    #: The run's output folder (timeseries.csv, summary.json, plots, run.mcap).
    out: Path
    command: List[str]
    #: What climbsim printed (stdout, stderr).
    output: str = ""
    errors: str = ""

    def __bool__(self) -> bool:
        return self.passed

    def __repr__(self) -> str:
        # Short: pytest prints it beside a failed assertion, where the whole summary and output
        # would bury climbsim's lines.
        return f"RunResult(passed={self.passed}, exit_code={self.exit_code}, out={str(self.out)!r}, {len(self.failures.lines)} failure line(s))"


def _finish(command: List[str], completed: "subprocess.CompletedProcess[str]", out: Path) -> RunResult:
    """A run's result from its exit code and summary.json; an exception when climbsim did not
    get as far as a verdict (bad input, interrupted)."""
    summary_path = out / "summary.json"
    if completed.returncode in (EXIT_PASSED, EXIT_FAILED) and summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as error:
            raise ClimbsimError(f"cannot read {summary_path}: {error}", exit_code=completed.returncode, command=command, output=completed.stdout, errors=completed.stderr) from error
        lines = [str(f) for f in summary.get("failures", [])]
        if completed.returncode != EXIT_PASSED and not lines:
            lines.append(_climbsim_lines(completed.stderr))
        failures = Failures("\n".join(lines))
        return RunResult(completed.returncode == EXIT_PASSED, completed.returncode, summary, failures, out, command, completed.stdout, completed.stderr)
    message = _climbsim_lines(completed.stderr)
    # `check` says why a scenario could not run on stdout, under its ERROR line.
    verdict_lines = [line for line in completed.stdout.splitlines() if line.startswith(("ERROR ", "    "))]
    if verdict_lines:
        message = "\n".join(verdict_lines) + "\n" + message
    raise ClimbsimError(message, exit_code=completed.returncode, command=command, output=completed.stdout, errors=completed.stderr)


def _call(command: List[str], timeout_s: Optional[float], env: Optional[Mapping[str, str]]) -> "subprocess.CompletedProcess[str]":
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, env=_environment(env), check=False)
    except subprocess.TimeoutExpired as expired:
        raise ClimbsimError(f"climbsim did not finish within {timeout_s} s: {' '.join(command)}", command=command) from expired
    except OSError as error:
        raise ClimbsimError(f"cannot start {command[0]}: {error}", command=command) from error


def _default_out(scenario: Optional[PathLike], root: str) -> Path:
    stem = Path(os.fspath(scenario)).stem if scenario is not None else "flat-line"
    return Path(root) / stem


def run(
    scenario: Optional[PathLike] = None,
    *,
    controller: Optional[Sequence[PathLike]] = None,
    clock: Optional[str] = "virtual",
    sets: Optional[Mapping[str, Value]] = None,
    robot: Optional[PathLike] = None,
    out: Optional[PathLike] = None,
    args: Sequence[str] = (),
    binary: Optional[str] = None,
    env: Optional[Mapping[str, str]] = None,
    timeout_s: Optional[float] = None,
) -> RunResult:
    """`climbsim run`: run `scenario` (the built-in flat-line one if None) and return its
    verdict, summary and output folder (`out`, default `results/<scenario name>`).

    `controller` replaces the scenario's controller with an external one, a command such as
    `["python3", "./follower.py"]` (`./` and `../` from the current folder). `clock` is
    `"virtual"` (simulated time: fast and repeatable) or `"wall"` (None: climbsim's default). `sets`
    are `--set` keys: `{"world.duration_s": 5, "robot.wheel.friction": 0.35}`. `args` are further
    flags. Raises ClimbsimError when climbsim refuses (bad input) or is interrupted.
    """
    out_dir = Path(os.fspath(out)) if out is not None else _default_out(scenario, "results")
    command = [binary or find_binary(), "run"]
    if scenario is not None:
        command.append(os.fspath(scenario))
    command += ["--out", os.fspath(out_dir)]
    if clock is not None:
        command += ["--clock", clock]
    command += _flags(sets, controller, robot, args)
    return _finish(command, _call(command, timeout_s, env), out_dir)


def check(
    scenario: PathLike,
    *,
    controller: Optional[Sequence[PathLike]] = None,
    sets: Optional[Mapping[str, Value]] = None,
    robot: Optional[PathLike] = None,
    out: Optional[PathLike] = None,
    args: Sequence[str] = (),
    binary: Optional[str] = None,
    env: Optional[Mapping[str, str]] = None,
    timeout_s: Optional[float] = None,
) -> RunResult:
    """`climbsim check`: run one scenario against its `[expect]` thresholds, an external
    controller on virtual time (`args=["--clock", "wall"]` for the wall clock). `out` is the
    root of the output folders (default `results/check`); the result's `out` is the scenario's.
    Raises ClimbsimError when the scenario cannot be loaded or run."""
    scenario_path = Path(os.fspath(scenario))
    out_root = Path(os.fspath(out)) if out is not None else Path("results/check")
    command = [binary or find_binary(), "check", os.fspath(scenario_path), "--out", os.fspath(out_root)]
    command += _flags(sets, controller, robot, args)
    return _finish(command, _call(command, timeout_s, env), out_root / scenario_path.stem)


@dataclass
class Bus:
    """A served bus: its port (give it to your controller as you would /dev/ttyUSB0), the
    sensors' URL in a scenario's world (None on the bench), and the process."""

    port: str
    sensors: Optional[str]
    process: "subprocess.Popen[str]"
    #: Lines climbsim has printed so far (stdout).
    lines: List[str] = field(default_factory=list)
    #: What climbsim has written to its stderr so far (a function: it reads it afresh).
    stderr: Callable[[], str] = field(default=lambda: "", repr=False)

    def log(self) -> str:
        """What climbsim has said so far: its lines (stdout), then its stderr; for a failing
        test's report."""
        parts = ["\n".join(self.lines)]
        errors = self.stderr()
        if errors:
            parts.append("--- stderr ---\n" + errors.rstrip("\n"))
        return "\n".join(parts)


def _read_lines(stream: Any, into: "queue.Queue[Optional[str]]", lines: List[str]) -> None:
    for line in stream:
        lines.append(line.rstrip("\n"))
        into.put(line.rstrip("\n"))
    into.put(None)


@contextlib.contextmanager
def serve(
    scenario: Optional[PathLike] = None,
    *,
    sets: Optional[Mapping[str, Value]] = None,
    robot: Optional[PathLike] = None,
    link: Optional[PathLike] = None,
    args: Sequence[str] = (),
    binary: Optional[str] = None,
    env: Optional[Mapping[str, str]] = None,
    ready_timeout_s: float = 60.0,
    stop_timeout_s: float = 30.0,
) -> Iterator[Bus]:
    """`climbsim serve`: the eight servos on a pty, on the bench (no scenario) or in
    `scenario`'s world, for as long as the `with` block lasts; then SIGTERM, and climbsim writes
    what it was asked to (`args=["--report", "timing.json"]`). Yields a Bus once the port is
    there. Raises ClimbsimError if climbsim does not start, or ends with an error."""
    command = [binary or find_binary(), "serve"]
    if scenario is not None:
        command.append(os.fspath(scenario))
    if link is not None:
        command += ["--link", os.fspath(link)]
    command += _flags(sets, None, robot, args)
    errors = tempfile.TemporaryFile(mode="w+", encoding="utf-8")
    try:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=errors, text=True, env=_environment(env))
    except OSError as error:
        errors.close()
        raise ClimbsimError(f"cannot start {command[0]}: {error}", command=command) from error

    def stderr_text() -> str:
        # pread, not seek and read: climbsim writes through the same open file (its offset
        # shared), and may be writing now.
        if errors.closed:
            return ""
        size = os.fstat(errors.fileno()).st_size
        return os.pread(errors.fileno(), size, 0).decode("utf-8", errors="replace")

    lines: List[str] = []
    ready: "queue.Queue[Optional[str]]" = queue.Queue()
    reader = threading.Thread(target=_read_lines, args=(process.stdout, ready, lines), name="climbsim-serve-stdout", daemon=True)
    reader.start()
    try:
        port = _wait_until_served(process, ready, want_sensors=scenario is not None, timeout_s=ready_timeout_s, command=command, stderr_text=stderr_text)
        bus = Bus(port=port[0], sensors=port[1], process=process, lines=lines, stderr=stderr_text)
        failed_inside = False
        try:
            yield bus
        except BaseException:
            failed_inside = True
            raise
        finally:
            code = _stop(process, stop_timeout_s)
            reader.join(timeout=5.0)
            # SIGTERM is how a served bus ends: 0 or 130 (interrupted) are a clean end.
            if not failed_inside and code not in (0, 130, -signal.SIGTERM):
                raise ClimbsimError(_climbsim_lines(stderr_text()), exit_code=code, command=command, output="\n".join(lines), errors=stderr_text())
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        errors.close()


# What the wait for `port:` gets when its time is up (None: climbsim closed its output).
_TIMED_OUT = "\0timed out"
# How long a climbsim that closed its output gets to exit.
_EXIT_WAIT_S = 10.0


def _wait_until_served(process: "subprocess.Popen[str]", ready: "queue.Queue[Optional[str]]", *, want_sensors: bool, timeout_s: float, command: List[str], stderr_text: Callable[[], str]) -> Tuple[str, Optional[str]]:
    """The `port:` (and in a world `sensors:`) climbsim prints once it serves."""
    deadline = time.monotonic() + timeout_s
    port: Optional[str] = None
    sensors: Optional[str] = None
    while port is None or (want_sensors and sensors is None):
        left = deadline - time.monotonic()
        try:
            line = ready.get(timeout=left) if left > 0 else _TIMED_OUT
        except queue.Empty:
            line = _TIMED_OUT
        if line is _TIMED_OUT:
            process.kill()
            process.wait()
            raise ClimbsimError(f"climbsim serve did not serve within {timeout_s} s", command=command, errors=stderr_text())
        if line is None:
            # Its output closed: climbsim is ending (refused its input, say). Whether it has
            # exited yet is a race, so wait for it, then say why.
            try:
                process.wait(timeout=_EXIT_WAIT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            raise ClimbsimError(_climbsim_lines(stderr_text()), exit_code=process.returncode, command=command, errors=stderr_text())
        if line.startswith("port: "):
            port = line[len("port: "):]
        elif line.startswith("sensors: "):
            sensors = line[len("sensors: "):]
    return port, sensors


def _stop(process: "subprocess.Popen[str]", timeout_s: float) -> int:
    """End a served bus as Ctrl-C would (SIGTERM: outputs written), then SIGKILL past
    `timeout_s`."""
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            raise ClimbsimError(f"climbsim serve did not end within {timeout_s} s of SIGTERM (killed)")
    return process.returncode
