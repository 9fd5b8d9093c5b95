"""Host-side device driver for the north finder and the wire codec it shares with the simulator.

- :mod:`northfinder.driver.device`: :class:`~northfinder.driver.device.Device`, what a host application uses (identify,
  status, moves, configuration, streaming, ``acquire`` windows in physical units).
- :mod:`northfinder.driver.device_link`: what ``Device`` is built on: the reader that sorts what arrives, link
  supervision, requests with retries, :class:`~northfinder.driver.device_link.DeviceStatus` and ``LinkStats``.
- :mod:`northfinder.driver.window`: :class:`~northfinder.driver.window.Window` and the pure state machine that
  collects one (:class:`~northfinder.driver.window.WindowCollector`).
- :mod:`northfinder.driver.transport`: CAN (python-can) and serial (pyserial) transports under it.
- :mod:`northfinder.driver.errors`: one root, :class:`~northfinder.driver.errors.DriverError`, and specific errors.
- :mod:`northfinder.driver.protocol`: the wire codec (no I/O, imports nothing outside itself), also used by
  the simulated firmware; its errors are in :mod:`northfinder.driver.protocol.errors`.
- :mod:`northfinder.driver.conformance`: the protocol conformance suite, on a raw link of its own.

``driver`` imports neither ``host`` nor ``firmware_sim`` (``tests/test_architecture.py`` checks it). This module imports nothing, so that
the codec can be used without the driver's dependencies being loaded.
"""
