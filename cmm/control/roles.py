"""What each role may do: the one table of every front end (page, pendant, I++, OPC UA, scripts with a token).

Four roles, each a set of the command API's verbs (by group; the users page of the docs prints :func:`table`):

=============  ==============================================================================================
role           may
=============  ==============================================================================================
operator       observe (every query), stop, take control, jog, move, probe, home, reset, run programs and
               routines, measure and construct features, align, notes, the report header, choose the probe
programmer     what an operator may, and define what is measured: nominals, tolerances, datums, GD&T, save
               taught routines
metrologist    what a programmer may, and calibrate: qualify probes, ISO 10360-5, geometry and servo tuning,
               save calibrations, accept gains, zero the axes, change the machine set-up
admin          everything, and manage the users
=============  ==============================================================================================

Rules kept here, checked once in :meth:`cmm.api.CommandAPI.invoke` (never in a front end):

- Without a user file the station runs in the local, no-login mode: no role is checked (the control holder rule
  of :mod:`cmm.control.access` alone decides), as a single-user bench always did.
- With one (:class:`RolePolicy`), a client that logged in carries its user and role (:class:`~cmm.control.access.
  Client`); a query is open to every client, anonymous observers too; STOP, E-STOP (also as the pendant's
  press and answer), cancel, pause and jog release (:data:`STOP_VERBS`) are never refused for a role: whoever
  the holder rule lets stop may (any user who logged in, the station PC, the holder); every other verb needs a
  role that lists it. A verb no group names needs the operator group's role; :func:`unnamed` lists such verbs
  and the tests keep it empty, so every verb's role is explicit.
- ``None`` as the client is the station itself (its scripts, the CLI, the homing cycle): never refused.
"""

from __future__ import annotations

from typing import Any

ROLES = ("operator", "programmer", "metrologist", "admin")
# never refused for a role: stopping (STOP, E-STOP and the pendant's press / answer pair of them), ending jobs and
# jogs, giving control back; the holder rule (Control.may_stop) decides who may
STOP_VERBS = frozenset({"stop", "estop", "press", "answer", "cancel", "pause", "jog_release", "release_control"})
GROUPS: dict[str, frozenset[str]] = {
    "operate": frozenset({
        "take_control", "move", "probe", "jog_hold", "step", "home", "reset", "reconnect", "resume", "skip_step",
        "cancel_move", "run_job", "run_program", "run_routine", "measure_feature", "construct", "undo", "delete_hit",
        "delete_feature", "refit_feature", "align", "auto_measure", "new_session", "new_part", "note", "set_info",
        "select_probe", "load_part", "place_sim_part", "run_dmis", "rename_session", "delete_session",
        "reevaluate_session", "add_probe", "set_sphere_certificate", "bar_placed"}),
    "program": frozenset({"set_nominal", "define_datum", "define_gdt", "delete_gdt", "record_event"}),
    "calibrate": frozenset({"qualify", "save_calibration", "accept_gains", "zero", "configure"}),
    "administer": frozenset({"users", "add_user", "remove_user", "set_password", "new_token", "revoke_token"}),
}
MAY: dict[str, tuple[str, ...]] = {  # role -> its groups
    "operator": ("operate",),
    "programmer": ("operate", "program"),
    "metrologist": ("operate", "program", "calibrate"),
    "admin": ("operate", "program", "calibrate", "administer"),
}


def check_role(role: str) -> str:
    """The role as written in the user file; ValueError names the four."""
    role = str(role or "").strip().lower()
    if role not in ROLES:
        raise ValueError(f"the role must be one of {', '.join(ROLES)}, not {role!r}")
    return role


def group_of(verb: str) -> str:
    """The verb's group; a verb no group names (a new one not yet in the table) falls to "operate"."""
    return next((g for g, verbs in GROUPS.items() if verb in verbs), "operate")


def unnamed(verbs: Any) -> list[str]:
    """The command verbs (``api.verbs()``) whose role is not explicit: not a query, not a stop verb, in no group.
    The tests keep this empty for every verb the station registers."""
    named = set().union(*GROUPS.values()) | STOP_VERBS
    return sorted(v.name for v in verbs if not v.query and v.name not in named)


def allowed(role: str | None, verb: str) -> bool:
    return role in MAY and group_of(verb) in MAY[role]


class RolePolicy:
    """The role check of a station with a user file: ``refusal(client, verb, query) -> str | None``."""

    def refusal(self, client: Any, verb: str, query: bool = False) -> str | None:
        if client is None or query or verb in STOP_VERBS:
            return None
        user, role = getattr(client, "user", None), getattr(client, "role", None)
        if user is None:
            return (f"{verb} needs a user: log in (this station has users and roles); anonymous clients only "
                    "observe")
        if allowed(role, verb):
            return None
        need = [r for r in ROLES if allowed(r, verb)]
        return f"{user} ({role}) may not {verb.replace('_', ' ')}: that needs the role {' or '.join(need)}"


def table() -> list[tuple[str, str, str]]:
    """(group, the roles that may, its verbs) for the documentation."""
    return [(g, ", ".join(r for r in ROLES if g in MAY[r]), ", ".join(sorted(v))) for g, v in GROUPS.items()]
