"""Users and roles: the user file (argon2id hashes, API tokens), the one role table enforced in the command API
(every front end's verbs), STOP for any user who logged in, and the local no-login mode unchanged."""

from __future__ import annotations

import os
import stat

import pytest

from cmm.cli import main
from cmm.control import Client, CommandAPI
from cmm.control.access import AccessRefused, Control, HolderPolicy
from cmm.control.roles import ROLES, RolePolicy, allowed, table
from cmm.control.users import LoginError, UserStore


def test_the_user_file_keeps_argon2_hashes_and_token_digests_never_the_secrets(tmp_path):
    store = UserStore(tmp_path / "users.toml")
    store.add("maria", "operator", "correct horse")
    store.add("li", "metrologist", "battery staple")
    token = store.new_token("maria", "spc-export")
    text = (tmp_path / "users.toml").read_text()
    assert "correct horse" not in text and token not in text and "$argon2id$" in text
    assert stat.S_IMODE(os.stat(tmp_path / "users.toml").st_mode) == 0o600
    again = UserStore(tmp_path / "users.toml")  # read back as another process would
    assert again.login("maria", "correct horse").role == "operator"
    assert again.login("token", token).user == "maria"
    with pytest.raises(LoginError, match="wrong user name or password"):
        again.login("maria", "wrong password")
    with pytest.raises(LoginError, match="wrong user name or password"):
        again.login("nobody", "correct horse")
    again.revoke_token("maria", "spc-export")
    with pytest.raises(LoginError):
        UserStore(tmp_path / "users.toml").login_token(token)
    with pytest.raises(ValueError, match="one of operator, programmer, metrologist, admin"):
        store.add("tom", "boss", "long enough")
    with pytest.raises(ValueError, match="at least 8"):
        store.add("tom", "operator", "short")
    store.passwd("li", "new password!")
    assert store.authenticate("li", "battery staple") is None
    assert store.authenticate("li", "new password!") == "metrologist"
    store.remove("li")
    assert [u["name"] for u in store.users()] == ["maria"]


def test_the_role_table_is_enforced_in_the_api_for_every_front_end(sim_machine, tmp_path):
    from cmm.control import Controller

    sim, machine, prober = sim_machine
    controller = Controller(machine, prober)
    controller.use_policy_of(Control(lan=True))
    controller.connect()
    api: CommandAPI = controller.commands
    calls = {}
    api.register("qualify", lambda client, **kw: calls.setdefault("qualify", client), {"routine": "probe"}, "test")
    api.register("define_gdt", lambda client, **kw: calls.setdefault("gdt", client), {}, "test")
    api.roles = RolePolicy()
    operator = Client("page 1", authenticated=True, user="maria", role="operator")
    programmer = Client("pendant 2", authenticated=True, user="tom", role="programmer")
    metrologist = Client("opcua li", authenticated=True, user="li", role="metrologist")
    anonymous = Client("page 3")
    # queries are open to everyone, commands need a role that lists them, refused in the operator's words
    assert api.call(anonymous, "state").ok and api.call(anonymous, "job").ok
    refused = api.call(anonymous, "take_control")
    assert refused.error["code"] == "refused" and "needs a user: log in" in refused.error["message"]
    refused = api.call(operator, "qualify")
    assert refused.error["message"] == "maria (operator) may not qualify: that needs the role metrologist or admin"
    assert api.call(operator, "define_gdt").error["code"] == "refused"
    assert api.call(programmer, "define_gdt").ok and calls["gdt"] is programmer
    assert api.call(programmer, "qualify").error["code"] == "refused"
    assert api.call(metrologist, "qualify").ok
    # a user takes control without an access code, and the holder's name is the person's
    assert api.call(operator, "take_control").result["message"] == "maria controls the machine"
    assert controller.holder.holder_name == "maria"
    # STOP: any user who logged in, never refused for a role; an anonymous LAN observer is refused
    assert api.call(programmer, "stop").ok
    assert api.call(anonymous, "stop").error["code"] == "refused"
    # the station itself (None) is never refused
    assert api.call(None, "qualify").ok
    # the admin manages the users through the API (the page's Users folder); nobody else may
    from cmm.control.users import register_user_verbs

    store = UserStore(tmp_path / "users.toml")
    store.add("ada", "admin", "admin password")
    register_user_verbs(api, store)
    admin = Client("page 5", authenticated=True, user="ada", role="admin")
    assert api.call(admin, "add_user", {"name": "maria", "role": "operator", "password": "correct horse"}).ok
    assert [u["name"] for u in api.call(admin, "users").result] == ["ada", "maria"]
    assert api.call(metrologist, "users").error["message"] == ("li (metrologist) may not users: that needs the role "
                                                              "admin")
    token = api.call(admin, "new_token", {"name": "maria", "label": "mes"}).result
    assert store.login_token(token).user == "maria"
    # the local, no-login mode: no user file, no role checked (the holder rule alone)
    api.roles = None
    local = Client("page 4", local=True)
    assert api.call(local, "take_control").ok and api.call(local, "qualify").ok
    controller.close()


def test_every_role_in_the_documented_table():
    rows = {group: roles for group, roles, _ in table()}
    assert rows == {"operate": "operator, programmer, metrologist, admin", "program": "programmer, metrologist, admin",
                    "calibrate": "metrologist, admin", "administer": "admin"}
    assert not allowed("metrologist", "add_user") and allowed("admin", "add_user")
    assert all(allowed(r, "take_control") for r in ROLES) and not allowed(None, "move")
    assert isinstance(RolePolicy().refusal(None, "zero"), type(None))
    assert AccessRefused and HolderPolicy


def test_cmm_users_manages_the_file_from_the_command_line(tmp_path, capsys, monkeypatch):
    path = tmp_path / "users.toml"
    monkeypatch.setattr("sys.stdin", __import__("io").StringIO("pass-word-1\n"))
    assert main(["users", "--file", str(path), "add", "maria", "--role", "programmer", "--password-stdin"]) == 0
    assert main(["users", "--file", str(path), "list"]) == 0
    assert "maria" in capsys.readouterr().out
    assert main(["users", "--file", str(path), "token", "maria", "--label", "mes"]) == 0
    token = capsys.readouterr().out.strip().splitlines()[-1].split()[-1]
    assert UserStore(path).login_token(token).role == "programmer"
    monkeypatch.setattr("sys.stdin", __import__("io").StringIO("other-pass-2\n"))
    assert main(["users", "--file", str(path), "passwd", "maria", "--password-stdin"]) == 0
    assert UserStore(path).authenticate("maria", "other-pass-2") == "programmer"
    assert main(["users", "--file", str(path), "remove", "maria"]) == 0
    assert main(["users", "--file", str(path), "remove", "maria"]) == 2
    assert "there is no user 'maria'" in capsys.readouterr().err


def test_a_pendant_over_tls_logs_in_and_its_role_decides(stations, tmp_path):
    """The pendant served over https / wss with the station's self-signed certificate (checked by its file, as a
    client that was given the printed fingerprint would): an anonymous connection only observes, a wrong password
    is refused without saying which part was wrong, a logged-in operator takes control under the person's name and
    is refused calibration in the role table's words."""
    import json
    import ssl

    from netutil import WssClient

    from cmm.control import tls
    from cmm.ui.pendant import start_pendant_server

    store = UserStore(tmp_path / "users.toml")
    store.add("maria", "operator", "correct horse")
    cert = tls.certificate(tmp_path / "tls")
    assert cert.made and tls.certificate(tmp_path / "tls").fingerprint == cert.fingerprint  # made once, then reused
    station = stations.station(home=False, session_dir=tmp_path / "sessions")
    control = Control()
    station.controller.use_policy_of(control)
    station.controller.commands.roles = RolePolicy()
    server = start_pendant_server(station.controller.commands, control, "127.0.0.1", 0, ssl=cert.ssl_context(), users=store)
    try:
        assert server.ws_url.startswith("wss://")
        trust = ssl.create_default_context(cafile=str(cert.cert_path))
        # a TLS handshake beside CPU hogs; a client whose TLS socket one thread uses (netutil.WssClient says why)
        ws = WssClient(server.ws_url, ssl=trust, open_timeout=60, close_timeout=2)

        def ask(**msg):
            ws.send(json.dumps(msg))
            while True:
                answer = json.loads(ws.recv(timeout=30))
                if answer.get("type") in ("hello", "login", "error", "result", "control"):
                    return answer

        assert ask(type="hello")["users"] is True  # the page shows its login row
        refused = ask(type="call", id=1, method="take_control")
        assert refused["error"]["code"] == "refused" and "needs a user: log in" in refused["error"]["message"]
        assert ask(type="login", user="maria", password="wrong one!")["message"] == "wrong user name or password"
        assert ask(type="login", user="maria", password="correct horse") == {"type": "login", "user": "maria",
                                                                            "role": "operator"}
        assert ask(type="call", id=2, method="take_control")["result"]["message"] == "maria controls the machine"
        refused = ask(type="call", id=3, method="qualify")
        assert refused["error"]["message"] == "maria (operator) may not qualify: that needs the role metrologist or admin"
        assert ask(type="call", id=4, method="stop")["result"]["ok"] is True
        ws.close()
        # I++ DME has no login: its clients act as the user the operator named (--ippdme-user), or only observe
        from cmm.ippdme.backend import StationBackend

        api = station.controller.commands
        anonymous = StationBackend(api, grants_control=True).for_client("10.0.0.5:5000")
        assert "needs a user: log in" in anonymous.acquire()
        named = StationBackend(api, grants_control=True, user=("maria", "operator")).for_client("10.0.0.5:5001")
        assert named.acquire() is None and control.holder_name == "maria"
    finally:
        server.close()
        station.close()


def test_a_page_tab_logs_in_in_its_start_dialog_and_only_an_admin_manages_users(tmp_path_factory):
    """The station page with a user file: a tab logs in (a wrong password refused in one sentence), then acts as
    its user: control under the person's name, the Users folder's verbs refused for an operator and done for an
    admin (the API decides)."""
    import ui_support
    from cmm.control.users import register_user_verbs

    store = UserStore(tmp_path_factory.mktemp("users") / "users.toml")
    store.add("maria", "operator", "correct horse")
    store.add("ada", "admin", "admin password")
    gen = ui_support.station_app(tmp_path_factory, pendant=False, users=store, home=False)
    app = next(gen)
    try:
        app.station.controller.commands.roles = RolePolicy()
        register_user_verbs(app.station.controller.commands, store)
        with ui_support.viser_tab(app) as (_ws, capp):
            assert not capp.log_in("maria", "not her password")
            assert capp.ctx.messages[-1][2] == "wrong user name or password"
            assert capp.take_control("") is False  # nobody logged in: observe only
            assert capp.log_in("maria", "correct horse")
            assert capp.ctx.who().user == "maria" and capp.ctx.who().role == "operator"
            assert capp.take_control("") is True and app.control.holder_name == "maria"
            assert capp.users_action("add_user", name="tom", role="programmer", password="pass-word-3") is None
            assert "maria (operator) may not add user" in capp.ctx.messages[-1][2]
            assert capp.log_in("ada", "admin password")
            capp.users_action("add_user", name="tom", role="programmer", password="pass-word-3")
            assert store.authenticate("tom", "pass-word-3") == "programmer"
    finally:
        gen.close()


def test_cmm_serve_refuses_an_empty_user_file_and_a_half_given_certificate(tmp_path, capsys):
    empty = tmp_path / "users.toml"
    empty.write_text("")
    assert main(["serve", "--users", str(empty)]) == 2
    assert "no users in" in capsys.readouterr().err
    store = UserStore(tmp_path / "u.toml")
    store.add("maria", "operator", "correct horse")
    assert main(["serve", "--users", str(tmp_path / "u.toml"), "--ippdme-user", "tom"]) == 2
    assert "--ippdme-user tom: there is no such user" in capsys.readouterr().err
    assert main(["serve", "--tls-cert", str(tmp_path / "c.pem")]) == 2
    assert "give both the certificate and its key" in capsys.readouterr().err
