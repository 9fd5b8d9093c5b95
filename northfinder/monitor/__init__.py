"""``northfinder monitor``: a live terminal view of a unit (Textual).

- :mod:`~northfinder.monitor.observer`: what the frames of a link say (no screen, no clock of
  its own): state, stream, commands and replies with their delays, traces;
- :mod:`~northfinder.monitor.session`: the link, active (the driver) or passive (a bus only
  listened to), reopened when lost; a find run with its solution as it forms;
- :mod:`~northfinder.monitor.app`: the screen (needs the ``monitor`` extra: Textual and
  textual-plotext).
"""

from __future__ import annotations

from northfinder.monitor.observer import LinkObserver, View
from northfinder.monitor.session import ActiveSession, FindRun, MonitorSession, PassiveSession

__all__ = ["ActiveSession", "FindRun", "LinkObserver", "MonitorSession", "PassiveSession", "View"]
