"""Control authority: one holder, observers by default, codes for remote clients."""

from __future__ import annotations

import threading

import pytest

from cmm.control.access import Control


def test_everybody_starts_as_observer():
    control = Control(lan=True)
    assert control.holder is None
    assert not control.can_move("a")
    assert not control.can_move("")


def test_loopback_server_has_no_code_and_refuses_remote_clients():
    control = Control()
    assert control.access_code is None
    assert not control.take("remote", None)
    assert not control.take("remote", "")
    assert not control.take("remote", "anything")
    assert control.holder is None


def test_lan_server_generates_a_random_code():
    a, b = Control(lan=True), Control(lan=True)
    assert a.access_code and b.access_code and a.access_code != b.access_code
    assert len(a.access_code) >= 8


def test_local_client_takes_without_code():
    control = Control(lan=True)
    assert control.take("local", is_local=True)
    assert control.holder == "local"
    assert control.can_move("local")
    assert not control.can_move("other")


def test_remote_client_needs_the_right_code():
    clock = FakeClock()
    control = Control(access_code="s3cret", clock=clock)
    for code in (None, "wrong", "s3cre", 1234):
        assert not control.take("remote", code)  # type: ignore[arg-type]
        clock.t += 1.0  # past the rate limit's wait
    assert control.failed_attempts == 4
    assert control.holder is None
    assert control.take("remote", "s3cret")
    assert control.can_move("remote")


def test_takeover_rules_and_holder_lost_hook():
    lost: list[str] = []
    changes: list[tuple] = []
    control = Control(access_code="code", on_holder_lost=lost.append)
    control.on_change(lambda holder, previous: changes.append((holder, previous)))
    assert control.take("remote", "code")
    assert not control.take("intruder", "nope")  # wrong code: no takeover
    assert control.holder == "remote" and lost == []
    assert control.take("local", is_local=True)  # the person at the machine can always take over
    assert control.holder == "local" and lost == ["remote"]
    assert control.take("remote", "code")  # so can a remote client that has the code
    assert lost == ["remote", "local"]
    assert changes == [("remote", None), ("local", "remote"), ("remote", "local")]
    assert control.take("remote", "code")  # taking again is a no-op
    assert len(changes) == 3


def test_release_only_by_holder():
    lost: list[str] = []
    control = Control(on_holder_lost=lost.append)
    control.take("a", is_local=True)
    assert not control.release("b")
    assert control.holder == "a"
    assert control.release("a")
    assert control.holder is None and lost == ["a"]
    assert not control.release("a")


def test_holder_disconnect_releases_and_calls_hook():
    lost: list[str] = []
    control = Control(on_holder_lost=lost.append)
    control.take("a", is_local=True)
    control.disconnected("b")  # an observer leaving changes nothing
    assert control.holder == "a" and lost == []
    control.disconnected("a")
    assert control.holder is None and lost == ["a"]
    assert not control.can_move("a")


def test_broken_callback_does_not_keep_control_stuck():
    def boom(*_):
        raise RuntimeError("boom")

    control = Control(on_holder_lost=boom)
    control.on_change(boom)
    control.take("a", is_local=True)
    control.disconnected("a")
    assert control.holder is None
    assert control.errors


def test_unsubscribe_and_bad_arguments():
    seen = []
    control = Control()
    off = control.on_change(lambda h, p: seen.append(h))
    control.take("a", is_local=True)
    off()
    control.take("b", is_local=True)
    assert seen == ["a"]
    with pytest.raises(ValueError):
        control.take("", is_local=True)
    with pytest.raises(ValueError):
        Control(access_code="")


def test_concurrent_takes_leave_one_consistent_holder():
    control = Control(access_code="c")
    barrier = threading.Barrier(8)

    def worker(i: int) -> None:
        barrier.wait()
        for _ in range(200):
            control.take(f"c{i}", "c")
            control.release(f"c{i}")

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    # every take is followed by the same thread's release, and after the last take nobody takes again,
    # so the last taker's release must succeed: anything else means a lost or doubled update
    assert control.holder is None
    assert control.failed_attempts == 0


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_wrong_codes_are_rate_limited_per_client_with_a_growing_wait():
    clock = FakeClock()
    control = Control(access_code="right", clock=clock)
    assert control.try_take("a", "wrong", peer="10.0.0.9") == "wrong access code: control refused"
    # at once again: refused without even looking at the code, even the right one
    refusal = control.try_take("a", "right", peer="10.0.0.9")
    assert refusal is not None and "too many wrong access codes" in refusal
    assert control.holder is None
    # another address is not held up by the first one
    assert control.try_take("b", "wrong", peer="10.0.0.7") == "wrong access code: control refused"
    waits = []
    for _ in range(9):
        clock.t += 60.0  # long after any wait: a new attempt is looked at
        assert "wrong access code" in control.try_take("a", "nope", peer="10.0.0.9")
        state = control._attempts["10.0.0.9"]
        waits.append(round(state.not_before - clock.t, 6))
    # five attempts a second at first, then the wait doubles up to 30 s
    assert waits[:4] == [0.2] * 4 and waits[4] == 0.4 and waits[5] == 0.8 and waits[-1] == 6.4
    for _ in range(10):
        clock.t += 60.0
        control.try_take("a", "nope", peer="10.0.0.9")
    assert control._attempts["10.0.0.9"].not_before - clock.t == 30.0
    clock.t += 30.0
    assert control.try_take("a", "right", peer="10.0.0.9") is None  # the right code after the wait works
    assert control.holder == "a" and "10.0.0.9" not in control._attempts


def test_a_guessing_loop_gets_at_most_five_tries_a_second():
    clock = FakeClock()
    control = Control(access_code="7f3k", clock=clock)
    looked_at = 0
    for i in range(1000):  # 1000 attempts spread over one second
        clock.t = 1000.0 + i / 1000
        before = control.failed_attempts
        control.try_take("x", f"guess{i}", peer="192.0.2.1")
        looked_at += control.failed_attempts - before
    assert looked_at <= 5


def test_local_clients_are_never_rate_limited():
    clock = FakeClock()
    control = Control(access_code="c", clock=clock)
    for _ in range(3):
        control.try_take("remote", "bad", peer="127.0.0.1")
    assert control.try_take("me", None, is_local=True, peer="127.0.0.1") is None


def test_stop_policy_is_one_rule():
    control = Control(access_code="c")
    control.take("holder", "c")
    assert control.may_stop("holder", is_local=False)
    assert control.may_stop("someone", is_local=True)  # at the station PC: always
    assert control.may_stop("lan-user", is_local=False, authenticated=True)  # gave the code
    assert not control.may_stop("anonymous", is_local=False)
    with pytest.raises(PermissionError):
        control.set_lan_stop(True, is_local=False)  # a LAN client cannot open this for itself
    control.set_lan_stop(True, is_local=True)
    assert control.may_stop("anonymous", is_local=False)
