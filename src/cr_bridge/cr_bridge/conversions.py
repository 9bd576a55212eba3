"""Message layouts of the bridge's own topic (``diagnostics``); the robot interface itself is
:mod:`cr_sim.conversions`, shared with the simulator."""

from __future__ import annotations

from collections.abc import Mapping

from cr_sim.conversions import status_msg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

__all__ = ['LEVELS', 'diagnostics_msg', 'diagnostics_from_msg']

LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
          'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}


def diagnostics_msg(level: str, message: str, values: Mapping[str, object], t: float,
                    hardware_id: str) -> DiagnosticArray:
    """One status ``cr_bridge: link``: ``level`` (ok / warn / error), a message, counters."""
    return status_msg('cr_bridge: link', LEVELS[level], message, values, t, hardware_id)


def diagnostics_from_msg(msg: DiagnosticArray) -> tuple[int, str, dict[str, str]]:
    """``(level, message, values)`` of :func:`diagnostics_msg`."""
    s = msg.status[0]
    return int.from_bytes(s.level, 'little') if isinstance(s.level, bytes) else int(s.level), \
        s.message, {kv.key: kv.value for kv in s.values}
