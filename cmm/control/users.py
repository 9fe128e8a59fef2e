"""The station's users: a user file with names, roles (:mod:`cmm.control.roles`), password hashes and API tokens.

The file (TOML, written by ``cmm users`` and the admin's page, never by hand) holds for each user::

    [users.maria]
    role = "operator"
    password = "$argon2id$v=19$m=65536,t=3,p=4$..."     # argon2id (argon2-cffi), never the password
    tokens = [{label = "spc-export", sha256 = "9f2c...", created = "2026-11-28 23:50"}]

Passwords are hashed with argon2id (:class:`argon2.PasswordHasher`'s defaults); a hash made with weaker
parameters is re-hashed at the next good login. An API token is 32 random bytes (``secrets.token_urlsafe``),
shown once when made; the file keeps its SHA-256 (a token is high-entropy, so a fast hash is enough and lets a
token be found without trying every user). The file is written atomically with mode 0600.

A client logs in with a name and password, or with a token alone (programs: ``Authorization: Bearer``, the OPC
UA password field with the name ``token``). :meth:`UserStore.login` returns the :class:`Login` (name, role) or
raises :class:`LoginError` with a sentence that does not tell which of name or password was wrong.
"""

from __future__ import annotations

import hashlib
import json
import hmac
import os
import secrets
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .roles import ROLES, check_role

MIN_PASSWORD = 8
TOKEN_USER = "token"  # the name a program gives with a token as its password (OPC UA, the page's API)


class LoginError(PermissionError):
    """A login refused, in words that do not say which part was wrong."""


@dataclass(frozen=True)
class Login:
    user: str
    role: str


def _hasher() -> Any:
    from argon2 import PasswordHasher

    return PasswordHasher()


def check_name(name: str) -> str:
    name = str(name or "").strip()
    if not name or len(name) > 40 or not all(c.isalnum() or c in "._-" for c in name):
        raise ValueError(f"a user name is 1 to 40 letters, digits, '.', '_' or '-', got {name!r}")
    if name == TOKEN_USER:
        raise ValueError(f"{TOKEN_USER!r} is reserved: programs log in with it and a token")
    return name


def check_password(password: str) -> str:
    if not isinstance(password, str) or len(password) < MIN_PASSWORD:
        raise ValueError(f"a password has at least {MIN_PASSWORD} characters")
    return password


class UserStore:
    """The user file at ``path`` (created on the first ``add``); thread-safe, re-read when the file changes."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.RLock()
        self._users: dict[str, dict[str, Any]] = {}
        self._stamp: tuple[int, int] | None = None
        self.failed_logins = 0
        self._load()

    # --- file -----------------------------------------------------------------------------
    def _load(self) -> None:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            self._users, self._stamp = {}, None
            return
        stamp = (st.st_mtime_ns, st.st_size)
        if stamp == self._stamp:
            return
        try:
            data = tomllib.loads(self.path.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"the user file {self.path} cannot be read: {exc}") from None
        users = data.get("users", {})
        for name, entry in users.items():
            if entry.get("role") not in ROLES:
                raise ValueError(f"the user file {self.path}: user {name!r} has no valid role ({', '.join(ROLES)})")
        self._users, self._stamp = users, stamp

    def _save(self) -> None:
        def toml_value(v: Any) -> str:  # a TOML basic string (JSON's escapes are TOML's)
            return json.dumps(str(v), ensure_ascii=False)

        lines = ["# the station's users (cmm users ...): argon2id password hashes and SHA-256 of API tokens", ""]
        for name in sorted(self._users):
            e = self._users[name]
            lines.append(f"[users.{toml_value(name)}]")
            lines.append(f"role = {toml_value(e['role'])}")
            lines.append(f"password = {toml_value(e.get('password', ''))}")
            tokens = ", ".join("{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in t.items()) + "}"
                               for t in e.get("tokens", []))
            lines.append(f"tokens = [{tokens}]")
            lines.append("")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)
        st = self.path.stat()
        self._stamp = (st.st_mtime_ns, st.st_size)

    # --- management (cmm users, the admin's page) -----------------------------------------------
    def users(self) -> list[dict[str, Any]]:
        """name, role and token labels of every user (never a hash)."""
        with self._lock:
            self._load()
            return [{"name": n, "role": e["role"], "tokens": [t.get("label", "") for t in e.get("tokens", [])]}
                    for n, e in sorted(self._users.items())]

    def add(self, name: str, role: str, password: str) -> None:
        name, role = check_name(name), check_role(role)
        check_password(password)
        with self._lock:
            self._load()
            if name in self._users:
                raise ValueError(f"user {name!r} exists already (cmm users passwd to change the password)")
            self._users[name] = {"role": role, "password": _hasher().hash(password), "tokens": []}
            self._save()

    def remove(self, name: str) -> None:
        with self._lock:
            self._load()
            if self._users.pop(name, None) is None:
                raise ValueError(f"there is no user {name!r}")
            self._save()

    def set_role(self, name: str, role: str) -> None:
        with self._lock:
            self._entry(name)["role"] = check_role(role)
            self._save()

    def passwd(self, name: str, password: str) -> None:
        check_password(password)
        with self._lock:
            self._entry(name)["password"] = _hasher().hash(password)
            self._save()

    def new_token(self, name: str, label: str = "") -> str:
        """A new API token for ``name`` (shown once: the file keeps only its SHA-256)."""
        token = secrets.token_urlsafe(32)
        with self._lock:
            entry = self._entry(name)
            entry.setdefault("tokens", []).append({"label": str(label or f"token {len(entry['tokens']) + 1}"),
                                                   "sha256": _sha(token),
                                                   "created": time.strftime("%Y-%m-%d %H:%M")})
            self._save()
        return token

    def revoke_token(self, name: str, label: str) -> None:
        with self._lock:
            entry = self._entry(name)
            kept = [t for t in entry.get("tokens", []) if t.get("label") != label]
            if len(kept) == len(entry.get("tokens", [])):
                raise ValueError(f"{name} has no token {label!r}")
            entry["tokens"] = kept
            self._save()

    def _entry(self, name: str) -> dict[str, Any]:
        self._load()
        entry = self._users.get(name)
        if entry is None:
            raise ValueError(f"there is no user {name!r}")
        return entry

    # --- login --------------------------------------------------------------------------------
    def login(self, name: str, password: str) -> Login:
        """A name and password (or the name ``token`` and an API token); LoginError when refused."""
        from argon2.exceptions import InvalidHashError, VerificationError

        if name == TOKEN_USER:
            return self.login_token(password)
        with self._lock:
            self._load()
            entry = self._users.get(str(name or ""))
            if entry is None or not password:
                self.failed_logins += 1
                raise LoginError("wrong user name or password")
            hasher = _hasher()
            try:
                hasher.verify(entry.get("password", ""), password)
            except (VerificationError, InvalidHashError):
                self.failed_logins += 1
                raise LoginError("wrong user name or password") from None
            if hasher.check_needs_rehash(entry["password"]):
                entry["password"] = hasher.hash(password)
                self._save()
            return Login(str(name), entry["role"])

    def login_token(self, token: str) -> Login:
        digest = _sha(str(token or ""))
        with self._lock:
            self._load()
            for name, entry in self._users.items():
                for t in entry.get("tokens", []):
                    if hmac.compare_digest(str(t.get("sha256", "")), digest):
                        return Login(name, entry["role"])
        self.failed_logins += 1
        raise LoginError("unknown or revoked API token")

    def authenticate(self, name: str, password: str) -> str | None:
        """The role of a good login, None otherwise (the OPC UA server's check)."""
        try:
            return self.login(name, password).role
        except LoginError:
            return None

    def identify(self, name: str, password: str) -> tuple[str, str] | None:
        """(user, role) of a good login (a token names its holder), None otherwise (the OPC UA server's check)."""
        try:
            login = self.login(name, password)
        except LoginError:
            return None
        return login.user, login.role

    def __len__(self) -> int:
        with self._lock:
            self._load()
            return len(self._users)


def _sha(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def register_user_verbs(api: Any, store: UserStore) -> None:
    """The admin's verbs of the command API (the page's Users folder, scripts with an admin's token): the role
    table puts them in the ``administer`` group, so only an admin may; the file changes as ``cmm users`` does."""
    from ..api import REQUIRED

    api.register("users", lambda client: store.users(), {}, "the users, their roles and token labels (admin)")
    api.register("add_user", lambda client, name, role, password: store.add(name, role, password),
                 {"name": REQUIRED, "role": REQUIRED, "password": REQUIRED},
                 "add a user with a role and a password (admin)")
    api.register("remove_user", lambda client, name: store.remove(name), {"name": REQUIRED}, "remove a user (admin)")
    api.register("set_password", lambda client, name, password: store.passwd(name, password),
                 {"name": REQUIRED, "password": REQUIRED}, "set a user's password (admin)")
    api.register("new_token", lambda client, name, label="": store.new_token(name, label),
                 {"name": REQUIRED, "label": ""}, "an API token for a user, shown once (admin)")
    api.register("revoke_token", lambda client, name, label: store.revoke_token(name, label),
                 {"name": REQUIRED, "label": REQUIRED}, "revoke a user's token by its label (admin)")
