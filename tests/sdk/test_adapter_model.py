"""``climbsim serve --adapter``: the controller on the pty behind a modelled USB adapter.

The model's own rules have unit tests (src/transport/adapter.rs); here the official SDK sees
their effect. Only bounds the machine's load cannot break are asserted: the model delays
replies, and a loaded machine can only delay them more. The measured table against the
model's prediction is hil/bench/adapter_latency.py's (docs/hardware.md).
"""

from __future__ import annotations

import statistics
import time

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler

from conftest import A_PRESENT_POS, SERVO_IDS, describe


def ping_times(path: str, count: int) -> list[float]:
    port, ph = PortHandler(path), PacketHandler(2.0)
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        took = []
        for _ in range(count):
            start = time.perf_counter()
            _, result, error = ph.ping(port, 1)
            took.append(time.perf_counter() - start)
            assert result == COMM_SUCCESS, describe(ph, result, error)
        # A Sync Read of all eight still works behind the adapter (its replies come in packets).
        sync = GroupSyncRead(port, ph, A_PRESENT_POS, 4)
        for dxl_id in SERVO_IDS:
            sync.addParam(dxl_id)
        assert sync.txRxPacket() == COMM_SUCCESS
        return took
    finally:
        port.closePort()


def test_the_u2d2_model_holds_every_reply_for_its_latency_timer(start_emulator):
    emu = start_emulator("wire", ("--baud", "1000000", "--adapter", "u2d2"))
    took = ping_times(emu.port, 12)
    # Each reply is handed over at a timer expiry, each at a later one than the last (a ping is
    # sent only after the previous reply came). So pings 2..12 span at least ten whole 16 ms
    # periods. A single ping is no bound: one handed over late on a loaded machine makes the
    # next one shorter, because the timer's phase does not move.
    assert sum(took[1:]) > 10 * 0.016, [f"{t * 1e3:.2f}" for t in took]


def test_a_1_ms_latency_timer_and_the_ideal_adapter_answer_within_a_few_ms(start_emulator):
    tuned = start_emulator("wire", ("--baud", "1000000", "--adapter", "u2d2", "--latency-timer-ms", "1"))
    took = ping_times(tuned.port, 12)
    # Held for the 1 ms timer: never sooner than the wire (0.74 ms) allows, never a 16 ms period.
    assert 0.0007 < statistics.median(took) < 0.0145, [f"{t * 1e3:.2f}" for t in took]
    ideal = start_emulator("wire", ("--baud", "1000000"))
    assert statistics.median(ping_times(ideal.port, 12)) < 0.0145


def test_a_latency_timer_without_a_modelled_adapter_is_refused(start_emulator):
    import subprocess
    from conftest import climbsim_bin

    run = subprocess.run([str(climbsim_bin()), "serve", "--latency-timer-ms", "4"], capture_output=True, text=True, timeout=20)
    assert run.returncode == 2 and "--adapter u2d2" in run.stderr, run.stderr
