"""The link process (cmm/nmc/link_process.py): a real port is driven from a process of its own, which runs the
jog dead-man and the release next to the bus, and stops every axis when the station dies.

The simulated CMM runs as its own process in real time (`cmm sim --cmm --tcp`), as hardware would; the
station side is a Machine (or a Controller) on its socket:// URL. No test asserts wall-clock timing: they
check who stopped the jog (the guard's record), that the axes stand still, and what the station shows.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from cmm.control import Controller, Mode
from cmm.machine.config import load
from cmm.machine.motion import GROUP, Machine
from cmm.nmc import codec
from cmm.nmc.bus import Bus, LinkError
from cmm.nmc.link_process import CALL_TIMEOUT, GuardHeld, RemoteBus, separate_process
from test_kill9 import _config, _start_sim, jog_until_moved, last_seen, read_ready, standing, stopping_bound

pytestmark = pytest.mark.timeout(120)
HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    config = _config(tmp_path_factory.mktemp("link"))
    sim, url = _start_sim(config)
    yield config, url
    sim.send_signal(signal.SIGINT)
    try:
        sim.wait(5)
    except subprocess.TimeoutExpired:
        sim.kill()


@pytest.fixture
def ctl(served):
    config, url = served
    # a dead-man of 1 s: the dead-man runs from each hold's moment, and a test thread holding the jog on a
    # loaded host can be off the CPU for more than 0.15 s; these tests check who stops the jog, not how soon
    c = Controller(Machine(dataclasses.replace(load(config), deadman_timeout=1.0), url))
    c.connect()
    c.start()
    c.move(None, [40.0, 0.0, 300.0], frame="machine").wait(60)
    yield c
    c.close()


def _jog_until_fast(c: Controller, v=(40.0, 0.0, 0.0)) -> None:
    """Hold the jog (a refresh every 50 ms, as the pendant does) until X runs at speed."""
    end = time.monotonic() + 5
    while time.monotonic() < end:
        c.jog(None, list(v))
        time.sleep(0.05)
        if max(abs(a.velocity) for a in c.state.machine.axes) > 35:
            return
    raise AssertionError("the jog never reached speed")


def _wait(pred, timeout=5.0) -> bool:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


@contextlib.contextmanager
def _holding(c: Controller, v):
    """An operator holding the jog button: a refresh every 30 ms from a thread of its own until the event
    it yields is set."""
    done = threading.Event()

    def hold() -> None:
        while not done.is_set():
            try:
                c.jog(None, v)
            except Exception:  # noqa: BLE001 - refused once released: the holder lets go
                return
            time.sleep(0.03)
    t = threading.Thread(target=hold)
    t.start()
    try:
        yield done
    finally:
        done.set()
        t.join(5)


@contextlib.contextmanager
def _stuck_loop(bus: RemoteBus):
    """Another thread holds the pipe to the link process, as a machine loop stuck in a call would."""
    held, done = threading.Event(), threading.Event()

    def hold() -> None:
        with bus.lock:
            held.set()
            done.wait(10)
    t = threading.Thread(target=hold)
    t.start()
    try:
        assert held.wait(5)
        yield
    finally:
        done.set()
        t.join(5)


def _still(url_bus: RemoteBus, address: int) -> bool:
    st = url_bus.transact(codec.read_stat(address, codec.SEND_VEL), codec.SEND_VEL)
    return st.velocity == 0


def test_real_ports_get_a_link_process_and_the_simulator_does_not():
    assert separate_process("socket://127.0.0.1:7777", "auto")
    assert separate_process("/dev/ttyUSB0", "auto")
    assert not separate_process("sim://?cmm=1", "auto")
    assert not separate_process("/dev/ttyUSB0", "same")


def test_release_from_another_thread_is_carried_out_by_the_link_process(ctl):
    m = ctl.machine
    assert isinstance(m.bus, RemoteBus) and m.guarded and m.bus.alive
    _jog_until_fast(ctl)
    with _holding(ctl, [40.0, 0.0, 0.0]) as let_go:  # held until the release: no dead-man stop first
        let_go.set()  # the button comes up: no new refresh (one on its way is refused after the release)
        # the pendant's thread: no machine loop, no lock, no reply awaited
        t = threading.Thread(target=ctl.jog_release, args=(None,))
        t.start()
        t.join(5)
    assert _wait(lambda: ctl.state.mode == Mode.IDLE), ctl.state
    epoch, fired = m.bus.guard
    assert fired == "release" and epoch >= 1
    assert _still(m.bus, 1)
    # the station saw the stop: the guard holds nothing, the next move starts
    ctl.move(None, [40.0, 0.0, 300.0], frame="machine").wait(60)
    assert np.allclose(ctl.state.machine.position, [40.0, 0.0, 300.0], atol=0.01)


def test_a_jog_nobody_refreshes_is_stopped_by_the_link_process_dead_man(ctl):
    events = []
    ctl.subscribe(lambda kind, info: events.append(kind))
    _jog_until_fast(ctl)
    # no more refreshes: the station keeps sampling, but only the link process decides
    assert _wait(lambda: ctl.state.mode == Mode.IDLE), ctl.state
    assert ctl.machine.bus.guard[1] == "deadman"
    assert _wait(lambda: "deadman" in events), events
    assert _still(ctl.machine.bus, 1)


def test_after_a_guard_stop_the_stations_restart_of_the_jog_is_refused_until_it_saw_the_stop(ctl):
    m = ctl.machine
    bus = m.bus
    spec = m._guard_spec(np.array([10.0, 0.0, 0.0]))
    bus.guard_jog(spec)
    bus.guard_release()
    with pytest.raises(GuardHeld):
        bus.start_move(GROUP)  # a re-target still on its way when the operator let go: never carried out
    pos = ctl.state.machine.axes[0].counts
    with pytest.raises(GuardHeld):
        bus.transact(codec.load_traj(1, position=pos + 5000, velocity=100000, acceleration=1000))
    bus.transact(codec.load_traj(1, velocity=0, acceleration=1000, velocity_mode=True))  # a stop always passes
    bus.guard_clear()
    assert bus.transact(codec.stop_motor(1, codec.STOP_ABRUPT | codec.AMP_ENABLE)) is not None


def test_a_jog_sent_before_a_release_is_refused_by_the_link_process(ctl):
    bus = ctl.machine.bus
    # a long dead-man: only the release may stop this jog, however late its message is on a busy host
    spec = dataclasses.replace(ctl.machine._guard_spec(np.array([10.0, 0.0, 0.0])), deadman=10.0)
    bus.guard_jog(spec, 0)
    bus.release_now(1)  # the operator let go (release number 1)
    assert _wait(lambda: bus.stats is not None and bus.guard[1] == "release")  # any call brings the guard's state
    with pytest.raises(GuardHeld):
        bus.guard_jog(spec, 0)  # a refresh the loop was still carrying when the release came
    bus.guard_jog(spec, 1)  # pressed again after the release: a new jog
    bus.guard_release()
    bus.guard_clear()


def test_a_dead_link_process_puts_the_station_in_fault_and_the_axis_stops(ctl, served):
    url = served[1]
    _jog_until_fast(ctl)
    os.kill(ctl.machine.bus.pid, signal.SIGKILL)
    # seen at the next call, as its pipe closes (0.05 s here), or at worst when that call times out: once, in a loaded
    # suite, the pipe gave no end of file and the call waited its CALL_TIMEOUT. A bound, not a timing assertion
    end = time.monotonic() + 3 * CALL_TIMEOUT
    while time.monotonic() < end and ctl.state.mode != Mode.FAULT:
        try:
            ctl.jog(None, [40.0, 0.0, 0.0])  # still held: refused once the fault is seen
        except Exception:  # noqa: BLE001 - a refusal or the failure itself
            pass
        time.sleep(0.05)
    assert ctl.state.mode == Mode.FAULT
    assert "link process" in ctl.state.reason, ctl.state.reason
    # nobody drives the link now: the modules stop at the jog's horizon goal by themselves (the simulator runs in
    # a process of its own: asked until X stands, so a busy computer only makes the wait longer)
    bus = Bus(url)
    bus._set_host_baud(115200)
    try:
        end = time.monotonic() + 30
        while (st := bus.transact(codec.read_stat(1, codec.SEND_VEL), codec.SEND_VEL)).velocity != 0:
            assert time.monotonic() < end, f"X still moves at {st.velocity} counts/tick with nobody driving it"
            time.sleep(0.05)
    finally:
        bus.close()
    # the way back: Reconnect starts a new link process (the modules are restarted)
    ctl.reconnect(None)
    assert ctl.state.mode != Mode.FAULT and ctl.machine.bus.alive, ctl.state
    ctl.move(None, [40.0, 0.0, 300.0], frame="machine").wait(60)


def test_an_unreachable_port_is_a_clear_error_and_leaves_no_process(served):
    config, _ = served
    with pytest.raises(OSError) as err:  # TransportError (an OSError), raised in the station's thread
        Machine(load(config), "socket://127.0.0.1:9")
    assert "cannot open serial port" in str(err.value)


def test_kill_9_of_the_station_the_link_process_stops_the_axis_and_exits(served):
    config, url = served
    cfg = load(config)
    station = subprocess.Popen([sys.executable, str(HERE / "station_kill_helper.py"), url, str(config), "0",
                                "40", "0", "300"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        link_pid = read_ready(station)
        lines = jog_until_moved(station, 0, cfg.axes[0].max)  # it is jogging
        os.kill(station.pid, signal.SIGKILL)
        killed_at = time.monotonic()
        station.wait(10)
        lines += [line.rstrip() for line in station.stdout]  # positions printed before the kill landed
        seen_at, seen = last_seen(lines, 0)
        # the link process saw the station's pipe close, stopped every axis and ended
        assert _wait(lambda: not os.path.exists(f"/proc/{link_pid}") or _zombie(link_pid), 10)
        x = standing(url, cfg.axes[0])
        # no further than the jog could go from the station's last sample until the kill, the dead-man and braking
        assert x - seen <= stopping_bound(cfg, seen_at, killed_at), (seen, x, stopping_bound(cfg, seen_at, killed_at))
    finally:
        if station.poll() is None:
            station.kill()


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except OSError:
        return True


# --- the guard itself, next to an in-process bus on the virtual clock (deterministic) -------------------------

def _read(bus, address):
    items = codec.SEND_POS | codec.SEND_VEL | codec.SEND_AUX
    return bus.transact(codec.read_stat(address, items), items)


def test_a_guard_stop_stands_the_jog_still_within_its_stopping_distance(sim_machine):
    from cmm.nmc.link_process import JogGuard

    _, m, _ = sim_machine
    m.move_to([100.0, 100.0, 200.0]).wait()
    v = np.array([40.0, 0.0, 0.0])
    for _ in range(8):  # at speed, as the station jogs it
        m.jog(v)
        m.run_for(0.05)
    guard = JogGuard(m.bus)
    guard.arm(m._guard_spec(v))
    pos, t, vel, _ = m.bus.last_reading(1)
    assert abs(vel) > 0
    guard.stop("release")
    assert guard.held and guard.state.fired == "release"
    m.bus.clock.sleep(0.3)  # nobody re-targets: only the guard's stop acts
    st = _read(m.bus, 1)
    assert st.velocity == 0
    cpm = m.config.axes[0].counts_per_mm
    travelled = (st.position - pos) / cpm
    a = m.config.accelerations.stop
    # from the last reading: the time since it, the braking distance at the stop deceleration, the margin
    # (+0.5 mm: the quantised velocity reading, the module re-planning at speed); a horizon-only stop is 4.8 mm on
    bound = 40.0 * (m.bus.clock.now() - 0.3 - t) + 40.0 ** 2 / (2 * a) + 40.0 * 0.02 + 0.5
    assert 0 < travelled <= bound, (travelled, bound)
    with pytest.raises(GuardHeld):
        guard.check("start_move", ())


def test_when_the_station_dies_the_guard_never_switches_a_motor_off_axis_back_on(sim_machine):
    from cmm.nmc.link_process import JogGuard

    _, m, _ = sim_machine
    m.modules[0].stop("off")  # X: amplifier off (an E-stop, or a servo off for the operator)
    guard = JogGuard(m.bus)
    guard.station_gone()
    x, y = _read(m.bus, 1), _read(m.bus, 2)
    assert not x.aux & codec.AUX_SERVO_ON  # still off
    assert y.aux & codec.AUX_SERVO_ON and y.velocity == 0  # held where it stands


def test_stop_all_and_guard_clear_do_not_wait_for_the_loops_pipe(ctl):
    bus = ctl.machine.bus
    _jog_until_fast(ctl)
    with _stuck_loop(bus):  # as if the machine loop were waiting on a call to the link process
        report = bus.stop_all("abrupt")  # STOP and E-STOP go by the second pipe
        assert report.ok and set(report.acknowledged) == {1, 2, 3}, report
        bus.guard_clear()  # a fault path finishing a jog: deferred, not waited for
        assert bus._clear_due
    assert _still(bus, 1)  # this call also sends the deferred clear first
    assert not bus._clear_due


def test_a_driven_jog_runs_on_the_link_process_readings_and_never_pushes_on_after_a_contact(sim_machine):
    from cmm.nmc.link_process import JogGuard

    _, m, _ = sim_machine
    m.move_to([250.0, 190.0, 44.0]).wait()  # 3 mm above the part's top face (Z 40, tip radius 1)
    v = np.array([0.0, 0.0, -10.0])
    m.jog(v)  # the station starts the jog (capture armed on the probe input) ...
    guard = JogGuard(m.bus)
    spec = m._guard_spec(v)
    assert spec.drive
    guard.arm(spec)  # ... and from here only the link process re-targets it (the station loop is silent)
    zs = []
    for _ in range(100):  # 1 s: long past the horizon (0.12 s) the station's last goal allowed
        m.bus.clock.sleep(0.01)
        guard.refresh(None)  # the operator holds the button
        guard.drive(spec)
        zs.append(m.config.axes[2].to_mm(m.bus.last_reading(3)[0]))
    assert guard.state.fired == "contact" and guard.held
    assert min(zs) < 42.0  # past where the station's own last goal (one horizon, 1.2 mm below 44) ended
    z = m.config.axes[2].to_mm(_read(m.bus, 3).position)
    assert 40.9 < z < 41.1, z  # the tip centre stopped at the surface (pre-travel), not pushed through it
    with pytest.raises(GuardHeld):
        guard.check("start_move", ())


def test_a_driven_jog_stopped_early_by_the_dead_man_starts_again_on_the_next_hold(sim_machine):
    """A station slow to refresh a new jog (a loaded host) lets the dead-man stop it a few tenths of a mm into its
    acceleration; the operator still holds the button and the next hold restarts it. The restart's first goal
    (one horizon ahead of where the axis stopped) lies near the goal driven before the stop: it must still be
    sent, or the axis stands while the guard thinks it drives the jog (once in CI: Z stopped 0.5 mm into it)."""
    from cmm.nmc.link_process import JogGuard

    _, m, _ = sim_machine
    m.move_to([100.0, 100.0, 200.0]).wait()
    v = np.array([40.0, 0.0, 0.0])
    guard = JogGuard(m.bus)
    spec = m._guard_spec(v)
    x0 = m.config.axes[0].to_mm(_read(m.bus, 1).position)
    guard.arm(spec)  # the jog's first goal: one horizon (4.8 mm) ahead
    m.bus.clock.sleep(0.05)  # 0.5 mm into the acceleration ...
    guard.stop("deadman")  # ... the dead-man stops it (no refresh came in time)
    m.bus.clock.sleep(0.3)
    stopped = m.config.axes[0].to_mm(_read(m.bus, 1).position)
    assert _read(m.bus, 1).velocity == 0 and 0.2 < stopped - x0 < 2.0, (x0, stopped)
    guard.arm(spec)  # the operator still holds the button: a hold heard now restarts the jog
    for _ in range(30):  # the link process drives it (RUN_PERIOD), the holds keep coming
        m.bus.clock.sleep(0.01)
        guard.refresh(None)
        guard.drive(spec)
    x = m.config.axes[0].to_mm(_read(m.bus, 1).position)
    assert guard.state.fired is None and x - stopped > 5.0, (stopped, x)  # 0.3 s at up to 40 mm/s


def test_a_driven_jog_goes_on_while_the_station_loop_is_stuck(ctl):
    m = ctl.machine
    _jog_until_fast(ctl, (0.0, 40.0, 0.0))
    y0 = ctl.state.machine.position[1]
    with _stuck_loop(m.bus):  # the station's machine loop gets nothing through to the link process
        end = time.monotonic() + 1.0
        while time.monotonic() < end:  # the pendant's thread still hears the operator
            m.jog_alive(ctl._release_epoch)
            time.sleep(0.02)
        m.release_now(ctl._release_epoch + 1)  # ... and the release
    ctl.jog_release(None)
    assert _wait(lambda: ctl.state.mode == Mode.IDLE), ctl.state
    # far beyond one horizon (4.8 mm) and its braking: the link process drove the jog on its own readings
    assert ctl.state.machine.position[1] - y0 > 15.0, (y0, ctl.state.machine.position[1])
    # stopped by the release; or, on a host so busy that this thread's refreshes came over 0.15 s apart,
    # rightly by the dead-man
    assert m.bus.guard[1] in ("release", "deadman")


def test_a_goal_sent_just_after_a_contact_is_undone_at_once(sim_machine):
    """The race: the probe touches after the reading the link process re-targets from. The reply to the new
    goal shows the capture fired, and the axis is stopped again before it pushes into the part."""
    from cmm.nmc.link_process import JogGuard

    _, m, _ = sim_machine
    m.move_to([250.0, 190.0, 44.0]).wait()
    v = np.array([0.0, 0.0, -10.0])
    m.jog(v)
    guard = JogGuard(m.bus)
    spec = m._guard_spec(v)
    guard.arm(spec)
    stale = None
    for _ in range(100):
        before = {a: m.bus.last_reading(a) for a in (1, 2, 3)}
        m.bus.clock.sleep(0.01)
        guard.drive(spec)
        if guard.state.fired == "contact":
            stale = before  # the last readings that still showed the capture armed
            break
    assert stale is not None and all(r.status & codec.HOME_IN_PROG for r in stale.values())
    z_touch = m.config.axes[2].to_mm(_read(m.bus, 3).position)
    # replay the race: a reading from before the contact, a jog still armed, a goal due
    now = m.bus.clock.now()  # readings that look fresh, so no new reading is taken first
    m.bus._last.update({a: r._replace(time=now) for a, r in stale.items()})
    guard.state.fired, guard.held, guard.goals = None, False, {}
    guard.drive(spec)
    assert guard.state.fired == "contact"
    m.bus.clock.sleep(0.3)
    z = m.config.axes[2].to_mm(_read(m.bus, 3).position)
    assert z > z_touch - 0.01, (z_touch, z)  # not pushed on (a goal 1.2 mm further down was sent and undone)


def test_cmm_serves_default_simulator_is_driven_through_a_link_process(tmp_path):
    """`cmm serve` with no port runs the simulated CMM served on loopback in real time: the station reaches
    it as it reaches hardware, through its link process, which runs the jog and its release."""
    from cmm.station import Station

    station = Station(session_dir=tmp_path).start()
    try:
        m = station.machine
        assert m.guarded and isinstance(m.bus, RemoteBus) and m.bus.port_name.startswith("socket://127.0.0.1:")
        for _ in range(6):
            station.controller.jog(None, [0.0, 20.0, 0.0])
            time.sleep(0.05)
        station.controller.jog_release(None)
        assert _wait(lambda: station.controller.state.mode in (Mode.IDLE, Mode.NOT_HOMED)
                     and not station.controller.state.machine.moving), station.controller.state
        assert m.bus.guard[1] == "release"
    finally:
        station.close()
