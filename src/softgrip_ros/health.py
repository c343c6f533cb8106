"""How well a part of the suite is doing, in the terms /diagnostics reports: a level, a message
and named values. The cores (estimator, pressure controller, grasp state machine) each give a
:class:`Report`; the nodes turn it into a ``diagnostic_msgs/DiagnosticStatus`` unchanged."""
from __future__ import annotations

import dataclasses
import enum


class Health(enum.IntEnum):
    """A DiagnosticStatus level: OK, WARN, ERROR (the same values)."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclasses.dataclass(frozen=True)
class Report:
    """``health``, a one-line ``message`` and ``values`` (key: value, shown as text)."""

    health: Health
    message: str
    values: dict

    def with_note(self, health: Health, note: str) -> Report:
        """At least ``health``, with ``note`` appended to the message."""
        message = f"{self.message}; {note}" if self.message else note
        return Report(max(self.health, health), message, self.values)
