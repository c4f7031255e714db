"""Hardware timing validation with the unchanged official SDK: half-duplex collisions,
baud mismatch, and the timing report ``climbsim serve --report FILE`` writes on exit.

At 57600 bps a 4-byte Read instruction takes 2.4 ms on the wire, the servo waits its Return
Delay Time (500 us) and its 15-byte reply takes 2.6 ms more. A controller that waits for each
reply never drives the line at the same time as a servo; one that writes its next instruction
right after the first puts it on the wire (its UART sends it as soon as the first has gone)
while the reply is coming back, and both packets arrive corrupted, as on a real bus.
"""

import json

import dynamixel_sdk
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler

from conftest import A_PRESENT_POS, BAUD, SERVO_IDS, describe

LOOPS = 20


def _start(start_emulator, tmp_path):
    report = tmp_path / "timing.json"
    emu = start_emulator("wire", ("--report", str(report)))
    port = PortHandler(emu.port)
    assert port.openPort(), f"PortHandler.openPort() failed on {emu.port}"
    assert port.setBaudRate(BAUD)
    return emu, port, PacketHandler(2.0), report


def _stop_and_read(emu, port, report):
    port.closePort()
    assert emu.stop() == 0, emu.diagnostics()
    assert report.is_file(), f"no report at {report}\n{emu.diagnostics()}"
    return json.loads(report.read_text())


def test_a_loop_that_waits_for_every_reply_has_no_collisions(start_emulator, tmp_path, monkeypatch):
    # The SDK gives up on a reply 2 x LATENCY_TIMER (16 ms) after the request: a client
    # descheduled that long on a loaded CI host (seen once: "There is no status packet!") times
    # out on a reply that came on time. The wire's timing is judged from the emulator's report
    # below, not from the client's clock; a longer timer keeps this test about the emulator.
    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 250)
    emu, port, ph, report = _start(start_emulator, tmp_path)
    for _ in range(LOOPS):
        for dxl_id in SERVO_IDS:
            data, result, error = ph.readTxRx(port, dxl_id, A_PRESENT_POS, 4)
            assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
    timing = _stop_and_read(emu, port, report)
    assert timing["requests"] == LOOPS * len(SERVO_IDS), timing
    assert timing["replies"] == LOOPS * len(SERVO_IDS), timing
    assert timing["collisions"] == 0, timing
    assert timing["frame_errors"] == 0, timing
    assert timing["latency_us"]["Read"]["count"] == LOOPS * len(SERVO_IDS), timing
    # Every reply came no earlier than the wire allows: 14 + 15 bytes at 57600 + 500 us.
    assert timing["latency_us"]["Read"]["p1_us"] >= (29 * 10 / 57600 + 500e-6) * 1e6 * 0.97, timing
    loop = timing["controller_loop"]
    assert loop is not None and loop["period_ms"]["count"] == LOOPS - 1, loop
    assert 0 < timing["bus_utilisation_pct"] <= 100, timing
    assert (tmp_path / "timing-latency.png").is_file()


def _send_back_to_back(port, ph, ids):
    """Read instructions for `ids`, built by the SDK and written in one go, as a controller that
    does not wait for replies does. One write keeps the test independent of how quickly Python
    gets from one call to the next on a loaded machine: the UART sends them back to back."""
    packets = []
    real_write = port.writePort
    port.writePort = lambda packet: packets.append(bytes(packet)) or len(packet)
    try:
        for dxl_id in ids:
            assert ph.readTx(port, dxl_id, A_PRESENT_POS, 4) == COMM_SUCCESS
            # The SDK guards its port with a busy flag; a hand-rolled loop has none.
            port.is_using = False
    finally:
        port.writePort = real_write
    assert real_write(b"".join(packets)) == sum(len(p) for p in packets)


def test_a_loop_that_sends_before_the_reply_has_arrived_collides_and_its_reads_fail(start_emulator, tmp_path):
    emu, port, ph, report = _start(start_emulator, tmp_path)
    failed_first = failed_second = 0
    for _ in range(LOOPS):
        _send_back_to_back(port, ph, [1, 2])
        port.is_using = True
        port.setPacketTimeout(4 + 11)
        _, result, _ = ph.readRx(port, 1, 4)
        failed_first += result != COMM_SUCCESS
        port.is_using = True
        port.setPacketTimeout(4 + 11)
        _, result, _ = ph.readRx(port, 2, 4)
        failed_second += result != COMM_SUCCESS
    # After the bad loop, a well-behaved transaction still works: the bus has recovered.
    port.clearPort()
    data, result, error = ph.readTxRx(port, 3, A_PRESENT_POS, 4)
    assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
    timing = _stop_and_read(emu, port, report)
    assert failed_first == LOOPS, f"{failed_first} of {LOOPS} corrupted first replies were accepted"
    assert failed_second == LOOPS, f"{failed_second} of {LOOPS} colliding instructions were answered"
    assert timing["collisions"] == LOOPS, timing
    assert timing["collided_bytes"] > 0, timing
    # The colliding instructions arrived garbled and were dropped like any bad packet.
    assert timing["frame_errors"] >= LOOPS, timing


def test_a_controller_at_the_wrong_baud_gets_no_replies_until_it_matches(start_emulator, tmp_path):
    emu, port, ph, report = _start(start_emulator, tmp_path)
    assert port.setBaudRate(1_000_000)
    for _ in range(3):
        _, result, _ = ph.ping(port, 1)
        assert result == COMM_RX_TIMEOUT, f"at 1 Mbps against 57600: {describe(ph, result, 0)}"
    assert port.setBaudRate(BAUD)
    model, result, error = ph.ping(port, 1)
    assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
    timing = _stop_and_read(emu, port, report)
    assert timing["baud_mismatch_packets"] == 3, timing
    warnings = [line for line in emu.stderr().splitlines() if "baud mismatch:" in line]
    assert len(warnings) == 1, "the mismatch is logged once:\n" + "\n".join(warnings)
    assert "1000000" in warnings[0] and "57600" in warnings[0], warnings[0]
