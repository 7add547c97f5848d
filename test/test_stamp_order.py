"""msg_adapters.StampOrder: reorderings are rejected, jumps back restart time."""
import pytest

from msg_adapters import TIME_JUMP_TOLERANCE_S, JointStateError, Reason, StampOrder

MS = 1_000_000


def _feed(order: StampOrder, stamps) -> list:
    """'ok', 'restart' or the rejection reason of each stamp, accepting what passes."""
    out = []
    for t in stamps:
        try:
            restart = order.check(t)
        except JointStateError as e:
            out.append(e.reason)
            continue
        order.accept(t, restart)
        out.append("restart" if restart else "ok")
    return out


def test_in_order_and_equal_stamps_pass():
    order = StampOrder()
    assert _feed(order, [0, 10 * MS, 10 * MS, 20 * MS]) == ["ok"] * 4
    assert order.last_ns == 20 * MS and order.jumps_back == 0


def test_a_step_back_within_the_tolerance_is_rejected_and_moves_nothing():
    order = StampOrder(0.5)
    res = _feed(order, [1000 * MS, 990 * MS, 500 * MS, 1010 * MS])
    assert res == ["ok", Reason.STAMP_BACKWARDS, Reason.STAMP_BACKWARDS, "ok"]
    assert order.jumps_back == 0 and order.last_ns == 1010 * MS
    with pytest.raises(JointStateError, match=r"by 10\.0 ms: within the 500 ms"):
        order.check(1000 * MS)


def test_a_jump_back_beyond_the_tolerance_restarts_time():
    order = StampOrder(0.5)
    replay = [k * 10 * MS for k in range(150)]            # 1.49 s of a 100 Hz bag
    res = _feed(order, replay + replay + [replay[-1] - 20 * MS])
    assert res == ["ok"] * 150 + ["restart"] + ["ok"] * 149 + [Reason.STAMP_BACKWARDS]
    assert order.jumps_back == 1 and order.last_ns == replay[-1]
    # just beyond the tolerance is a restart, exactly at it a reordering
    assert order.check(replay[-1] - 500 * MS - 1) is True
    with pytest.raises(JointStateError):
        order.check(replay[-1] - 500 * MS)


def test_check_alone_neither_moves_time_nor_counts():
    """A message whose stamp passes but whose body is rejected must not restart time."""
    order = StampOrder(0.5)
    _feed(order, [5000 * MS])
    assert order.check(0) is True
    assert order.jumps_back == 0 and order.last_ns == 5000 * MS


def test_tolerance_default_zero_and_bad_values():
    assert StampOrder().tolerance_s == TIME_JUMP_TOLERANCE_S == 0.5
    order = StampOrder(0.0)                               # every step back is a restart
    assert _feed(order, [10, 9, 8]) == ["ok", "restart", "restart"]
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match=">= 0 s"):
            StampOrder(bad)
