"""Control authority: one holder, observers by default, codes for remote clients."""

from __future__ import annotations

import threading

import pytest

from cmm.ui.access import Control


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
    control = Control(access_code="s3cret")
    assert not control.take("remote")
    assert not control.take("remote", "wrong")
    assert not control.take("remote", "s3cre")
    assert not control.take("remote", 1234)  # type: ignore[arg-type]
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
    holder = control.holder
    assert holder is None or control.can_move(holder)
