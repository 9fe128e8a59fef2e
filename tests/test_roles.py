"""Every verb's role is explicit: each verb the station, the DMIS runner and the user file register is a query, a
stop verb or in a role group (the one table of cmm/control/roles.py, printed in docs/users.md), and STOP / E-STOP
are never refused for a role, also as the pendant's press / answer pair."""

from __future__ import annotations

import re
from pathlib import Path

from cmm.control import Client, Controller
from cmm.control.access import Control
from cmm.control.roles import GROUPS, STOP_VERBS, RolePolicy, unnamed
from cmm.control.users import UserStore, register_user_verbs
from ippdme_support import SIM_URL, nist_config

DOCS = Path(__file__).resolve().parents[1] / "docs" / "users.md"


def test_every_verb_the_station_registers_has_an_explicit_role(stations, tmp_path):
    from cmm.dmis.runner import register_verbs

    station = stations.station(config=nist_config(), port=SIM_URL, start=False, session_dir=tmp_path / "sessions")
    try:
        api = station.controller.commands
        register_verbs(station.controller.commands)  # run_dmis
        register_user_verbs(api, UserStore(tmp_path / "users.toml"))  # the admin's verbs
        names = {v.name for v in api.verbs()}
        assert {"run_dmis", "load_part", "place_sim_part", "press", "answer", "add_user"} <= names
        assert unnamed(api.verbs()) == [], "verbs without an explicit role group (add them to roles.GROUPS)"
        # a verb nobody put in the table is still caught (and falls to the operate group meanwhile)
        api.register("new_verb_for_the_test", lambda client: None, {}, "test")
        assert unnamed(api.verbs()) == ["new_verb_for_the_test"]
    finally:
        station.close()


def test_the_documented_table_names_the_same_verbs_as_the_code():
    rows = {}
    for line in DOCS.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] in (*GROUPS, "stop"):
            rows[cells[0]] = set(re.findall(r"`([a-z_]+)`", cells[2]))
    assert rows.pop("stop") == set(STOP_VERBS)
    assert rows == {g: set(v) for g, v in GROUPS.items()}


def test_stop_and_estop_are_never_refused_for_a_role_also_as_the_pendants_press(sim_machine):
    sim, machine, prober = sim_machine
    controller = Controller(machine, prober)
    controller.use_policy_of(Control(lan=True))
    controller.connect()
    try:
        api = controller.commands
        api.roles = RolePolicy()
        local = Client("pendant 1", local=True)  # at the station PC, nobody logged in yet
        user = Client("pendant 2", authenticated=True, user="maria", role="operator")
        for client in (local, user):
            for verb in ("stop", "estop"):
                pressed = api.call(client, "press", {"verb": verb})
                assert pressed.ok, pressed.error
                assert api.call(client, "answer", {"pressed": pressed.result}).ok
                assert api.call(None, "reset").ok
            assert api.call(client, "stop").ok and api.call(client, "estop").ok
            assert api.call(None, "reset").ok
        # an anonymous LAN observer is not refused for a role either: the holder rule decides (no access code)
        lan = api.call(Client("pendant 3"), "press", {"verb": "stop"})
        assert lan.error["code"] == "refused" and "anonymous LAN observer" in lan.error["message"]
        assert "needs a user" in api.call(local, "move", {"target": [0, 0, 0], "frame": "machine"}).error["message"]
    finally:
        controller.close()
