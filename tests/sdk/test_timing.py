"""Wire timing (``--timing wire``, also the default without ``--timing``): a reply starts no
earlier than the end of the instruction (bytes x 10 / baud) + Return Delay Time x 2 us and
takes its own bytes x 10 / baud. Only lower bounds are asserted, on the fastest of several
round trips, so a loaded machine cannot make these flaky."""

import time

import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead

from conftest import A_BAUD, A_PRESENT_POS, A_RDT, SERVO_IDS, describe


def _fastest(fn, n=10):
    best = float("inf")
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _wire_s(n_bytes, bps):
    return n_bytes * 10 / bps


def _ping_checked(dxl, dxl_id=1):
    def run():
        model, result, error = dxl.ping(dxl_id)
        assert result == COMM_SUCCESS and error == 0, describe(dxl.ph, result, error)

    return run


@pytest.mark.timing("default")
def test_default_timing_is_wire_ping_round_trip(dxl):
    rtt = _fastest(_ping_checked(dxl))
    bound = _wire_s(10 + 14, 57600) + 500e-6  # ~4.67 ms
    assert rtt >= bound, f"fastest ping round trip {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms (no --timing flag)"


@pytest.mark.timing("wire")
def test_wire_timing_ping_round_trip(dxl):
    rtt = _fastest(_ping_checked(dxl))
    bound = _wire_s(10 + 14, 57600) + 500e-6
    assert rtt >= bound, f"fastest ping round trip {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms"


@pytest.mark.timing("wire")
def test_wire_timing_read_round_trip(dxl):
    def run():
        dxl.read_u(2, A_PRESENT_POS, 4)

    rtt = _fastest(run)
    bound = _wire_s(14 + 15, 57600) + 500e-6  # ~5.53 ms
    assert rtt >= bound, f"fastest 4-byte read round trip {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms"


@pytest.mark.timing("wire")
def test_wire_timing_follows_port_baud_9600(dxl):
    dxl.write_ok(1, A_BAUD, 1, 0)
    dxl.set_baud(9600)
    rtt = _fastest(_ping_checked(dxl), n=5)
    bound = _wire_s(10 + 14, 9600) + 500e-6  # ~25.5 ms
    assert rtt >= bound, f"fastest ping at 9600 bps {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms"


@pytest.mark.timing("wire")
def test_wire_timing_return_delay_zero(dxl):
    dxl.write_ok(3, A_RDT, 1, 0)
    rtt = _fastest(_ping_checked(dxl, 3))
    bound = _wire_s(10 + 14, 57600)  # ~4.17 ms: bytes alone
    assert rtt >= bound, f"fastest ping with RDT 0 {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms"


@pytest.mark.timing("wire")
def test_wire_timing_sync_read_replies_share_the_bus(dxl):
    group = GroupSyncRead(dxl.port, dxl.ph, A_PRESENT_POS, 4)
    for dxl_id in SERVO_IDS:
        assert group.addParam(dxl_id)

    def run():
        result = group.txRxPacket()
        assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)

    rtt = _fastest(run, n=5)
    # instruction 14 + 8 bytes, eight 15-byte replies one after another, at least one RDT
    bound = _wire_s(22 + 8 * 15, 57600) + 500e-6  # ~25.2 ms
    assert rtt >= bound, f"fastest 8-servo sync read {rtt * 1e3:.3f} ms < {bound * 1e3:.3f} ms"


def test_timing_off_is_much_faster(dxl):
    rtt = _fastest(_ping_checked(dxl), n=20)
    assert rtt < 3e-3, f"with --timing off the fastest ping still took {rtt * 1e3:.3f} ms"
