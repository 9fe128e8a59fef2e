"""I++ DME errors (spec 1.4.3, section 8.2): numbers, default severities and the texts the spec mandates."""

from __future__ import annotations

# number -> (default severity, text). The text must be the spec's text for that number.
ERRORS: dict[int, tuple[int, str]] = {
    0: (0, "Buffer full"),
    1: (2, "Illegal tag"),
    2: (2, "No space at pos. 6"),
    6: (2, "Transaction aborted (Use ClearAllErrors To Continue)"),
    7: (3, "Illegal character"),
    8: (3, "Protocol error"),
    500: (3, "Emergency stop"),
    501: (3, "Unsupported command"),
    502: (3, "Incorrect arguments"),
    503: (9, "Controller communications failure"),
    504: (1, "Argument out of range"),
    505: (3, "Argument not recognized"),
    506: (3, "Argument not supported"),
    507: (3, "Illegal command"),
    508: (3, "Bad context"),
    509: (3, "Bad argument"),
    510: (3, "Bad property"),
    511: (3, "Error processing method"),
    512: (1, "No daemons are active"),
    513: (2, "Daemon does not exist"),
    514: (2, "Use ClearAllErrors to continue"),
    515: (2, "Daemon already exists"),
    1000: (3, "Machine in error state"),
    1001: (2, "Illegal touch"),
    1002: (9, "Axis does not exist"),
    1003: (2, "No touch"),
    1004: (9, "Number of angles not supported on current device"),
    1005: (3, "Error during home"),
    1006: (2, "Surface not found"),
    1007: (3, "Theta out of range"),
    1008: (3, "Target position out of machine volume"),
    1009: (3, "Air pressure out of range"),
    1010: (2, "Vector has no norm"),
    1011: (2, "Unable to move"),
    1012: (2, "Bad lock combinations"),
    1500: (3, "Failed to re-seat head"),
    1501: (3, "Probe not armed"),
    1502: (3, "Tool not found"),
    1503: (3, "Tool not defined"),
    2000: (3, "Tool not calibrated"),
    2001: (2, "Head error excessive force"),
    2002: (3, "Type of probe does not allow this operation"),
    2500: (3, "Machine limit encountered [Move Out Of Limits]"),
    2501: (3, "Axis not active"),
    2502: (3, "Axis position error"),
    2503: (9, "Scale read head failure"),
    2504: (3, "Collision"),
    2505: (2, "Specified angle out of range"),
    2506: (2, "Part not aligned"),
}


class IppError(Exception):
    """An error response: ``Tag ! Error(severity, number, "method", "text")``.

    ``detail`` is our own explanation for logs and the session journal; the
    wire carries the spec's text only (clients match on it).
    """

    def __init__(self, number: int, method: str = "", detail: str = "", severity: int | None = None) -> None:
        if number not in ERRORS:
            raise ValueError(f"error {number} is not an I++ DME error number")
        default, text = ERRORS[number]
        self.number = number
        self.severity = default if severity is None else severity
        self.text = text
        self.method = method
        self.detail = detail
        self.sticky = True  # severity >= 2 puts the server in the error state (False: refused outside a session)
        super().__init__(f"{number:04d} {text}" + (f": {detail}" if detail else ""))
