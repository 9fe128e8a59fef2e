"""`cmm users`: the station's users and roles (add, list, remove, passwd, role, token, revoke).

The user file (default ``./users.toml``, or CMM_USERS) is what ``cmm serve --users FILE`` reads: with it the
station asks every client to log in and checks each command against the role table (the users page of the docs).
"""

from __future__ import annotations

import argparse
import getpass
import os
import sys

from . import action


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--file", metavar="FILE", default=os.environ.get("CMM_USERS", "users.toml"),
                        help="the user file (default: CMM_USERS, else ./users.toml)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = action(sub, "add", "add a user with a role and a password", "name")
    p.add_argument("--role", required=True, help="operator, programmer, metrologist or admin")
    p.add_argument("--password-stdin", action="store_true", help="read the password from standard input")
    sub.add_parser("list", help="the users, their roles and token labels")
    action(sub, "remove", "remove a user (and its tokens)", "name")
    p = action(sub, "passwd", "set a user's password", "name")
    p.add_argument("--password-stdin", action="store_true", help="read the password from standard input")
    action(sub, "role", "change a user's role", "name", "role")
    p = action(sub, "token", "make an API token for a program that acts as this user (shown once)", "name")
    p.add_argument("--label", default="", help="what the token is for (revoke names it)")
    action(sub, "revoke", "revoke a user's token by its label", "name", "label")


def _password(args: argparse.Namespace) -> str:
    if args.password_stdin:
        return sys.stdin.readline().rstrip("\n")
    first = getpass.getpass(f"password for {args.name}: ")
    if getpass.getpass("again: ") != first:
        raise ValueError("the two passwords differ")
    return first


def run(args: argparse.Namespace) -> int:
    from ..control.users import UserStore

    try:
        store = UserStore(args.file)
        if args.action == "add":
            store.add(args.name, args.role, _password(args))
            print(f"user {args.name} ({args.role.lower()}) added to {args.file}")
        elif args.action == "list":
            rows = store.users()
            if not rows:
                print(f"no users in {args.file}: the station runs in the local, no-login mode")
            for u in rows:
                tokens = f"  tokens: {', '.join(u['tokens'])}" if u["tokens"] else ""
                print(f"{u['name']:<20} {u['role']:<12}{tokens}")
        elif args.action == "remove":
            store.remove(args.name)
            print(f"user {args.name} removed")
        elif args.action == "passwd":
            store.passwd(args.name, _password(args))
            print(f"password of {args.name} changed")
        elif args.action == "role":
            store.set_role(args.name, args.role)
            print(f"{args.name} is now {args.role.lower()}")
        elif args.action == "token":
            token = store.new_token(args.name, args.label)
            print(f"API token for {args.name} (shown once; a program sends it as 'Authorization: Bearer TOKEN', or "
                  "logs in to OPC UA as user 'token' with it as the password):")
            print(token)
        elif args.action == "revoke":
            store.revoke_token(args.name, args.label)
            print(f"token {args.label!r} of {args.name} revoked")
    except (ValueError, OSError) as exc:
        print(f"cmm users: {exc}", file=sys.stderr)
        return 2
    return 0
