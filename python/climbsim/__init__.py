"""climbsim: a hardware-in-the-loop simulator for a magnetic wall-climbing welding robot,
eight Dynamixel XM540 servos on a pty with a rapier3d world behind them.

    import climbsim

    with climbsim.serve() as bus:                    # the servos on the bench
        port = PortHandler(bus.port)                 # your controller, unchanged

    result = climbsim.check("scenarios/line.toml")   # [expect] on virtual time
    assert result.passed, result.failures

The `climbsim` command itself is on PATH (or `python -m climbsim`); docs/python.md has it all.
"""

from ._api import Bus, Failures, RunResult, check, run, serve, toml_value
from ._binary import find_binary
from ._errors import ClimbsimError

__all__ = ["Bus", "ClimbsimError", "Failures", "RunResult", "check", "find_binary", "run", "serve", "toml_value"]
