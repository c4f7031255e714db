"""Your controller against climbsim, with its pytest plugin (installed with `pip install
climbsim`): every scenario in scenarios/ must pass its [expect], and the servos answer as the
real ones do. Run: pytest"""

from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

SCENARIOS = sorted((Path(__file__).resolve().parent.parent / "scenarios").glob("*.toml"))
XM540_W270_MODEL_NUMBER = 1120


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda path: path.stem)
def test_scenario_passes(climbsim_check, scenario):
    result = climbsim_check(scenario)
    assert result.passed, result.failures


def test_every_servo_answers_on_the_bench(climbsim_bus):
    port = PortHandler(climbsim_bus.port)
    assert port.openPort() and port.setBaudRate(57600)
    packet = PacketHandler(2.0)
    try:
        for dxl_id in range(1, 9):
            model, result, error = packet.ping(port, dxl_id)
            assert result == COMM_SUCCESS, packet.getTxRxResult(result)
            assert error == 0, packet.getRxPacketError(error)
            assert model == XM540_W270_MODEL_NUMBER
    finally:
        port.closePort()
