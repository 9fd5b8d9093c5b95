"""The control channel: JSON lines over a loopback TCP port or a Unix socket.

Tests and rehearsals use it to read and set the truth and the sensor parameters while the
simulator runs, to inject faults, and to pause, resume or change speed. Every request is a JSON
object with an ``op`` naming one entry of a fixed table; nothing received is ever executed as code.
Each reply is one JSON line: ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import json
import os
import socket
import socketserver
import threading
from collections.abc import Callable
from typing import Any

from northfinder.firmware_sim.errors import SimConfigError, SimError
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import Runner


class ControlError(SimError):
    """A control request that cannot be carried out (bad op or argument, or no answer)."""


def parse_address(text: str) -> tuple[str, Any]:
    """``("tcp", (host, port))`` for ``HOST:PORT`` on loopback, ``("unix", path)`` otherwise.

    Raises
    ------
    SimConfigError
        A TCP host that is not a loopback address: the channel must not be reachable from outside.
    """
    if text.startswith("unix:") or "/" in text:
        return "unix", text.removeprefix("unix:")
    host, sep, port = text.rpartition(":")
    if not sep:
        raise SimConfigError(f"control address {text!r}: expected HOST:PORT or unix:PATH")
    host = host.strip("[]") or "127.0.0.1"
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
        port_n = int(port)
    except ValueError:
        raise SimConfigError(f"control address {text!r}: bad host or port") from None
    if not loopback:
        raise SimConfigError(f"control address {text!r}: only loopback addresses are allowed")
    if not 0 <= port_n <= 65535:
        raise SimConfigError(f"control address {text!r}: port out of range")
    return "tcp", (host, port_n)


def _number(args: dict[str, Any], key: str, default: float | None = None) -> float:
    value = args.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ControlError(f"{key}: expected a number, got {value!r}")
    return float(value)


def _count(args: dict[str, Any], key: str = "count") -> int:
    value = args.get(key, 1)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 1_000_000:
        raise ControlError(f"{key}: expected a whole number from 0 to 1000000, got {value!r}")
    return value


def _vec3(args: dict[str, Any], key: str) -> tuple[float, float, float]:
    value = args.get(key, [0.0, 0.0, 0.0])
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise ControlError(f"{key}: expected a list of three numbers, got {value!r}")
    x, y, z = (float(v) for v in value)
    return x, y, z


class Controller:
    """Carries out control requests on a running simulator (thread-safe through the runner lock)."""

    def __init__(self, runner: Runner) -> None:
        self.runner = runner
        fw = runner.firmware
        self._ops: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
            "status": lambda a: self._status(),
            "get_truth": lambda a: {"truth": dataclasses.asdict(fw.instrument.truth)},
            "set_truth": self._set_truth,
            "get_sensor": lambda a: {"sensor": fw.instrument.spec.to_dict()},
            "set_sensor": self._set_sensor,
            "drop": lambda a: self._set_fault("drop_frames", _count(a)),
            "corrupt": lambda a: self._set_fault("corrupt_frames", _count(a)),
            "delay_replies": lambda a: self._set_fault("reply_delay_s", self._seconds(a)),
            "silent": lambda a: self._set_fault("silent", bool(a.get("on", True))),
            "skip_counter": lambda a: self._set_fault("skip_counter", _count(a)),
            "wrong_result": self._wrong_result,
            "stall": lambda a: self._call(fw.stall_table, bool(a.get("on", True))),
            "bias_step": lambda a: self._call(
                fw.apply,
                lambda: fw.instrument.inject_bias_step(_vec3(a, "gyro_dph"), _vec3(a, "accel_ug")),
            ),
            "impulses": self._impulses,
            "vibration": self._vibration,
            "reset": lambda a: self._call(self._reset),
            "pause": lambda a: self._call(runner.clock.pause),
            "resume": lambda a: self._call(runner.clock.resume),
            "speed": lambda a: self._call(runner.clock.set_speed, _number(a, "value")),
        }

    @property
    def ops(self) -> list[str]:
        return sorted(self._ops)

    def handle(self, request: Any) -> dict[str, Any]:
        """Carry out one request object; always returns a reply object."""
        if not isinstance(request, dict) or not isinstance(request.get("op"), str):
            return {"ok": False, "error": 'a request is a JSON object with a string "op"'}
        op = request["op"]
        fn = self._ops.get(op)
        if fn is None:
            return {"ok": False, "error": f"unknown op {op!r}; ops are {', '.join(self.ops)}"}
        try:
            with self.runner.lock:
                return {"ok": True, **fn(request)}
        except (SimError, ValueError, TypeError) as exc:
            return {"ok": False, "error": f"{op}: {exc}"}

    def _call(self, fn: Callable[..., Any], *args: Any) -> dict[str, Any]:
        fn(*args)
        return {}

    def _status(self) -> dict[str, Any]:
        fw = self.runner.firmware
        return {
            "time_s": fw.now,
            "state": fw.state.name,
            "streaming": fw.streaming,
            "sample_rate_hz": fw.sample_rate_hz,
            "rx_malformed": fw.rx_malformed,
            "tx_dropped": fw.tx_dropped,
            "cmd_rejected": fw.cmd_rejected,
            "table_deg": float(fw.instrument.table.encoder(fw.instrument.table.state(fw.now)[0])),
            "speed": self.runner.clock.speed,
            "paused": self.runner.clock.paused,
            "faults": dataclasses.asdict(fw.faults),
        }

    def _set_truth(self, args: dict[str, Any]) -> dict[str, Any]:
        fw = self.runner.firmware
        fields = {f.name for f in dataclasses.fields(Truth)}
        unknown = sorted(set(args) - fields - {"op"})
        if unknown:
            raise ControlError(
                f"unknown truth field {unknown[0]!r}; fields are {', '.join(sorted(fields))}"
            )
        values = {k: _number(args, k) for k in fields if k in args}
        truth = dataclasses.replace(fw.instrument.truth, **values)
        fw.set_truth(truth)
        return {"truth": dataclasses.asdict(truth)}

    def _set_sensor(self, args: dict[str, Any]) -> dict[str, Any]:
        fw = self.runner.firmware
        values = args.get("values")
        if not isinstance(values, dict):
            raise ControlError('set_sensor needs "values": {"gyro.arw_dpsh": 0.002, ...}')
        spec = fw.instrument.spec.with_values(values)
        fw.set_spec(spec)
        return {"sensor": spec.to_dict()}

    def _set_fault(self, name: str, value: Any) -> dict[str, Any]:
        faults = self.runner.firmware.faults
        self.runner.firmware.apply(lambda: setattr(faults, name, value))
        return {"faults": dataclasses.asdict(self.runner.firmware.faults)}

    @staticmethod
    def _seconds(args: dict[str, Any]) -> float:
        s = _number(args, "seconds")
        if not 0 <= s <= 3600:
            raise ControlError(f"seconds: expected 0 to 3600, got {s}")
        return s

    def _wrong_result(self, args: dict[str, Any]) -> dict[str, Any]:
        code = args.get("code", 7)
        if isinstance(code, bool) or not isinstance(code, int) or not 0 <= code <= 255:
            raise ControlError(f"code: expected a result code 0..255, got {code!r}")
        return self._set_fault("wrong_result", code)

    def _impulses(self, args: dict[str, Any]) -> dict[str, Any]:
        count = _count(args)
        fw = self.runner.firmware
        fw.apply(lambda: fw.instrument.inject_impulses(
            count,
            interval_s=_number(args, "interval_s", 0.5),
            gyro_dph=_number(args, "gyro_dph", 50.0),
            accel_ug=_number(args, "accel_ug", 5000.0),
        ))  # fmt: skip
        return {}

    def _vibration(self, args: dict[str, Any]) -> dict[str, Any]:
        fw = self.runner.firmware
        fw.apply(lambda: fw.instrument.set_vibration(
            bool(args.get("on", True)),
            hz=_number(args, "hz", 35.0),
            gyro_dph=_number(args, "gyro_dph", 5.0),
            accel_ug=_number(args, "accel_ug", 2000.0),
        ))  # fmt: skip
        return {}

    def _reset(self) -> None:
        fw = self.runner.firmware
        fw.apply(lambda: fw.instrument.table.stall(fw.now, False))
        fw.faults = type(fw.faults)()
        fw.reboot()


class _Handler(socketserver.StreamRequestHandler):
    server: _TcpServer | _UnixServer

    def handle(self) -> None:
        for raw in self.rfile:
            if len(raw) > 65536:
                reply: dict[str, Any] = {"ok": False, "error": "request line longer than 64 KiB"}
            else:
                try:
                    request = json.loads(raw)
                except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                    reply = {"ok": False, "error": f"not a JSON line: {exc}"}
                else:
                    reply = self.server.controller.handle(request)
            self.wfile.write(json.dumps(reply).encode() + b"\n")


class _TcpServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    controller: Controller


class _UnixServer(socketserver.ThreadingUnixStreamServer):
    daemon_threads = True
    controller: Controller


class ControlServer:
    """Serves a :class:`Controller` on a loopback TCP address or a Unix socket, in a thread."""

    def __init__(self, controller: Controller, address: str) -> None:
        kind, addr = parse_address(address)
        if kind == "unix" and os.path.exists(addr):
            os.unlink(addr)
        self._server = _TcpServer(addr, _Handler) if kind == "tcp" else _UnixServer(addr, _Handler)
        self._server.controller = controller
        self.kind = kind
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="control", daemon=True
        )

    @property
    def address(self) -> str:
        address = self._server.server_address
        if isinstance(address, tuple):
            host = address[0]
            host = host.decode() if isinstance(host, bytes | bytearray) else host
            return f"{host}:{address[1]}"
        return f"unix:{os.fsdecode(address) if isinstance(address, str | bytes) else address!r}"

    def start(self) -> ControlServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        address = self._server.server_address
        if self.kind == "unix" and isinstance(address, str | bytes):
            try:
                os.unlink(address)
            except OSError:
                pass


class ControlClient:
    """A small blocking client: ``client.call("drop", count=5)`` returns the reply object.

    Raises
    ------
    ControlError
        The simulator answered ``ok: false`` (its message is kept), or did not answer in time.
    """

    def __init__(self, address: str, timeout: float = 5.0) -> None:
        kind, addr = parse_address(address)
        family = socket.AF_INET6 if kind == "tcp" and ":" in addr[0] else socket.AF_INET
        self._sock = socket.socket(socket.AF_UNIX if kind == "unix" else family, socket.SOCK_STREAM)
        self._sock.settimeout(timeout)
        try:
            self._sock.connect(addr)
        except OSError as exc:
            self._sock.close()
            raise ControlError(
                f"cannot reach the simulator's control channel at {address}: {exc}"
            ) from exc
        self._file = self._sock.makefile("rwb")

    def call(self, op: str, **args: Any) -> dict[str, Any]:
        try:
            self._file.write(json.dumps({"op": op, **args}).encode() + b"\n")
            self._file.flush()
            line = self._file.readline()
        except OSError as exc:
            raise ControlError(f"control channel: {exc}") from exc
        if not line:
            raise ControlError("control channel closed by the simulator")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise ControlError(reply.get("error", "request refused"))
        return reply

    def close(self) -> None:
        self._file.close()
        self._sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
