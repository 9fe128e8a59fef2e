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


def test_the_role_table_is_enforced_in_the_api_for_every_front_end(sim_machine):
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
    # the local, no-login mode: no user file, no role checked (the holder rule alone)
    api.roles = None
    local = Client("page 4", local=True)
    assert api.call(local, "take_control").ok and api.call(local, "qualify").ok
    controller.close()


def test_every_role_in_the_documented_table():
    rows = {group: roles for group, roles, _ in table()}
    assert rows == {"operate": "operator, programmer, metrologist, admin", "program": "programmer, metrologist, admin",
                    "calibrate": "metrologist, admin", "administer": "admin"}
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
