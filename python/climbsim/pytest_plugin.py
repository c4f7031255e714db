"""climbsim's pytest plugin (installed with the wheel, entry point `pytest11`).

Fixtures:
  climbsim_bus     the servos served for one test, on the bench or in a scenario's world
                   (`@pytest.mark.climbsim_scenario("line.toml", sets={...})`); yields a Bus
                   (`.port`, `.sensors`), torn down after the test. A test body that fails
                   while it serves has climbsim's lines and stderr in its report.
  climbsim_check   a function: `climbsim_check("line.toml", controller=[...])` runs the scenario
                   against its [expect] on virtual time and returns a RunResult, so that
                   `assert result.passed, result.failures` shows climbsim's own lines.
  climbsim_run     the same for `climbsim run`.

Options: --climbsim-binary (or `climbsim_binary` in the ini file, or $CLIMBSIM_BINARY),
--climbsim-scenarios (or `climbsim_scenarios`: where relative scenario names are looked up;
default `scenarios` beside the ini file), --climbsim-out (where runs write; default each test's
tmp_path).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import pytest

from ._api import Bus, RunResult, check, run, serve
from ._binary import find_binary


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("climbsim")
    group.addoption("--climbsim-binary", default=None, help="the climbsim binary (default: the installed one, or $CLIMBSIM_BINARY)")
    group.addoption("--climbsim-scenarios", default=None, help="folder that relative scenario names are looked up in (default: scenarios/ beside the ini file)")
    group.addoption("--climbsim-out", default=None, help="root of the runs' output folders (default: each test's tmp_path)")
    parser.addini("climbsim_binary", "the climbsim binary", default="")
    parser.addini("climbsim_scenarios", "folder that relative scenario names are looked up in", default="scenarios")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "climbsim_scenario(path, sets=None, args=()): the scenario (and --set keys, flags) climbsim_bus serves")


def _binary(config: pytest.Config) -> str:
    given = config.getoption("--climbsim-binary") or config.getini("climbsim_binary")
    return str(given) if given else find_binary()


def pytest_report_header(config: pytest.Config) -> str:
    try:
        return f"climbsim: {_binary(config)}"
    except Exception as error:  # the header must not fail the session; the fixtures will say it
        return f"climbsim: {error}"


@pytest.fixture(scope="session")
def climbsim_binary(pytestconfig: pytest.Config) -> str:
    """The climbsim binary the fixtures run."""
    return _binary(pytestconfig)


@pytest.fixture(scope="session")
def climbsim_scenarios(pytestconfig: pytest.Config) -> Path:
    """The folder relative scenario names are looked up in."""
    given = pytestconfig.getoption("--climbsim-scenarios")
    if given:
        return Path(given).resolve()
    base = Path(pytestconfig.inipath).parent if pytestconfig.inipath else Path(pytestconfig.rootpath)
    return (base / str(pytestconfig.getini("climbsim_scenarios"))).resolve()


def _scenario_path(scenarios: Path, scenario: Any) -> Path:
    path = Path(scenario)
    return path if path.is_absolute() else scenarios / path


def _out_root(config: pytest.Config, tmp_path: Path) -> Path:
    given = config.getoption("--climbsim-out")
    return Path(given) if given else tmp_path / "climbsim"


@pytest.fixture
def climbsim_bus(request: pytest.FixtureRequest, climbsim_binary: str, climbsim_scenarios: Path) -> Iterator[Bus]:
    """The servos served for this test: on the bench, or in the world of the scenario that
    `@pytest.mark.climbsim_scenario(path, sets={...}, args=[...])` (or indirect
    parametrization) names."""
    marker = request.node.get_closest_marker("climbsim_scenario")
    scenario: Optional[Any] = getattr(request, "param", None)
    sets = None
    args: Any = ()
    if marker is not None:
        if marker.args:
            scenario = marker.args[0]
        sets = marker.kwargs.get("sets")
        args = marker.kwargs.get("args", ())
    path = _scenario_path(climbsim_scenarios, scenario) if scenario is not None else None
    with serve(path, sets=sets, args=args, binary=climbsim_binary) as bus:
        # For the test's report (an attribute, not pytest's stash: that needs pytest 7, and the
        # plugin loads in every pytest session of an environment climbsim is installed in).
        setattr(request.node, _BUS, bus)
        yield bus


# The attribute of a test item that holds the bus its `climbsim_bus` serves.
_BUS = "_climbsim_bus"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """A test that fails while `climbsim_bus` serves gets climbsim's own words in its report:
    the bus's lines and climbsim's stderr so far (as pytest shows a test's captured output)."""
    outcome = yield
    report = outcome.get_result()
    bus = getattr(item, _BUS, None)
    if bus is not None and report.when == "call" and report.failed:
        report.sections.append(("climbsim serve (its lines and stderr)", bus.log()))


@pytest.fixture
def climbsim_check(pytestconfig: pytest.Config, climbsim_binary: str, climbsim_scenarios: Path, tmp_path: Path) -> Callable[..., RunResult]:
    """`climbsim_check(scenario, controller=None, sets=None, **options)`: `climbsim check` of
    one scenario (relative names from the scenarios folder), on virtual time; a RunResult."""

    def check_one(scenario: Any, **options: Any) -> RunResult:
        options.setdefault("out", _out_root(pytestconfig, tmp_path))
        return check(_scenario_path(climbsim_scenarios, scenario), binary=climbsim_binary, **options)

    return check_one


@pytest.fixture
def climbsim_run(pytestconfig: pytest.Config, climbsim_binary: str, climbsim_scenarios: Path, tmp_path: Path) -> Callable[..., RunResult]:
    """`climbsim_run(scenario, controller=None, clock="virtual", sets=None, **options)`:
    `climbsim run` of one scenario; a RunResult."""

    def run_one(scenario: Any = None, **options: Any) -> RunResult:
        path = _scenario_path(climbsim_scenarios, scenario) if scenario is not None else None
        options.setdefault("out", _out_root(pytestconfig, tmp_path) / (Path(scenario).stem if scenario is not None else "flat-line"))
        return run(path, binary=climbsim_binary, **options)

    return run_one
