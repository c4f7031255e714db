"""The emulator process and its pty: link, reconnects, SIGTERM."""

import os
import time

from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from conftest import A_GOAL_VEL, A_LED, A_OP_MODE, A_PRESENT_POS, A_TORQUE, BAUD, MODEL_NUMBER, to_signed


def test_port_line_and_link(emulator_handle):
    emu = emulator_handle
    assert os.path.lexists(emu.link), f"link {emu.link} does not exist while the emulator runs"
    assert os.path.exists(emu.port), f"printed port {emu.port} does not exist"
    assert os.path.realpath(emu.port) == os.path.realpath(emu.link), (
        f"printed port {emu.port} and link {emu.link} are different devices"
    )


def test_close_and_reopen_port_keeps_working(dxl):
    dxl.write_ok(1, A_LED, 1, 1)
    dxl.port.closePort()
    assert dxl.port.openPort(), "reopen failed"
    dxl.set_baud(BAUD)
    dxl.ping_ok(1)
    assert dxl.read_u(1, A_LED, 1) == 1, "state lost across a client reconnect"


def test_new_client_after_previous_one_closed(dxl, emulator):
    dxl.write_ok(2, A_LED, 1, 1)
    dxl.port.closePort()
    for _ in range(3):
        port = PortHandler(emulator)
        assert port.openPort() and port.setBaudRate(BAUD)
        ph = PacketHandler(2.0)
        model, result, error = ph.ping(port, 2)
        assert (model, result, error) == (MODEL_NUMBER, 0, 0), f"ping after reconnect: {model} {result} {error}"
        value, result, error = ph.read1ByteTxRx(port, 2, A_LED)
        assert (value, result, error) == (1, 0, 0)
        port.closePort()


def test_sigterm_exits_zero_and_removes_link(start_emulator):
    emu = start_emulator()
    port = PortHandler(emu.port)
    assert port.openPort() and port.setBaudRate(BAUD)
    model, result, error = PacketHandler(2.0).ping(port, 1)
    assert result == 0 and model == MODEL_NUMBER
    rc = emu.stop()  # while the client still has the port open
    port.closePort()
    assert rc == 0, f"exit code {rc} after SIGTERM\n{emu.diagnostics()}"
    assert not os.path.lexists(emu.link), f"link {emu.link} left behind"


def test_two_emulators_side_by_side(start_emulator):
    a = start_emulator()
    b = start_emulator()
    assert a.port != b.port
    for emu in (a, b):
        port = PortHandler(emu.port)
        assert port.openPort() and port.setBaudRate(BAUD)
        model, result, error = PacketHandler(2.0).ping(port, 8)
        port.closePort()
        assert result == 0 and model == MODEL_NUMBER


def test_a_controller_that_reconnects_mid_run_finds_the_servos_as_the_physics_left_them(start_emulator):
    """Serving the robot in a world (scenarios/flat.toml), the controller starts the wheels,
    disconnects for a second, and comes back: torque and goal are as it left them and the wheel
    turned on meanwhile, because the world kept running on the wall clock without it."""
    emu = start_emulator("wire", ("scenarios/flat.toml",))
    port = PortHandler(emu.port)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = PacketHandler(2.0)
    goal = 50  # 0.229 rev/min units: 11.5 rev/min, 785 pulses a second
    for dxl_id in (1, 2, 3, 4):
        assert ph.write1ByteTxRx(port, dxl_id, A_OP_MODE, 1)[0] == COMM_SUCCESS
        assert ph.write1ByteTxRx(port, dxl_id, A_TORQUE, 1)[0] == COMM_SUCCESS
        assert ph.write4ByteTxRx(port, dxl_id, A_GOAL_VEL, goal)[0] == COMM_SUCCESS
    time.sleep(0.5)  # past the velocity loop's ramp
    before, result, _ = ph.read4ByteTxRx(port, 1, A_PRESENT_POS)
    assert result == COMM_SUCCESS
    port.closePort()
    away_s = 1.0
    t0 = time.monotonic()
    time.sleep(away_s)

    port = PortHandler(emu.port)
    assert port.openPort() and port.setBaudRate(BAUD)
    after, result, _ = ph.read4ByteTxRx(port, 1, A_PRESENT_POS)
    elapsed = time.monotonic() - t0
    assert result == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 1, A_TORQUE)[:2] == (1, COMM_SUCCESS), "torque stayed on"
    assert to_signed(ph.read4ByteTxRx(port, 1, A_GOAL_VEL)[0], 4) == goal, "goal kept"
    turned = to_signed(after - before, 4)
    expected = goal * 0.229 / 60 * 4096 * elapsed
    assert 0.8 * expected < turned < 1.2 * expected, (
        f"the wheel turned {turned} pulses in {elapsed:.2f} s away, expected about {expected:.0f}"
    )
    port.closePort()
