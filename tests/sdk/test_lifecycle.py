"""The emulator process and its pty: link, reconnects, SIGTERM."""

import os

from dynamixel_sdk import PacketHandler, PortHandler

from conftest import A_LED, BAUD, MODEL_NUMBER


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
