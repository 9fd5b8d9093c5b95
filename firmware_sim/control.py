"""The control channel: JSON lines over a loopback TCP port or a Unix socket.

Tests and rehearsals use it to read and set the truth and the sensor parameters while the
simulator runs, to inject faults, and to pause, resume or change speed. Every request is a JSON
object with an ``op`` naming one entry of :data:`OPS`; nothing received is ever executed as code.
Each reply is one JSON line: ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``.

Every argument is checked against its entry in :data:`OPS` (type, finite, inside stated bounds)
before anything changes, so nothing the channel accepts can stop the device or its stream: a
refusal names the key, the value and the bound. A request line is at most :data:`MAX_LINE_BYTES`
long; a longer one is refused without being held in memory.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import json
import logging
import os
import socket
import socketserver
import stat
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from northfinder.firmware_sim.errors import ControlError, ControlRefused, SimConfigError, SimError
from northfinder.firmware_sim.firmware import BASE_RATE_HZ
from northfinder.firmware_sim.runner import Runner

log = logging.getLogger("northfinder.sim.control")

#: Longest request line, bytes (without its newline).
MAX_LINE_BYTES = 65536
#: Longest burst of impulses one request may order (count x interval), s.
MAX_BURST_S = 86_400.0


def _num(x: float) -> str:
    """A bound as people write it: 100000, 0.01, 1e+20."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _show(value: Any, limit: int = 60) -> str:
    """``repr`` of a received value, shortened: a refusal must stay one short line."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 3]}..."


_REQUIRED = object()


@dataclass(frozen=True)
class Key:
    """One key of a control request, with the checks applied before the request acts.

    Parameters
    ----------
    kind : str
        ``"number"`` (finite int or float), ``"int"`` (whole number), ``"bool"`` (true/false),
        ``"vec3"`` (three numbers) or ``"fields"`` (an object of sensor fields).
    default : object
        Used when the key is absent; required keys have none, and ``None`` means "unchanged".
    lo, hi : float or None
        Inclusive bounds of a number, a whole number or each element of a vec3.
    unit : str
        Unit of the value, for the help text.
    """

    kind: str
    default: Any = _REQUIRED
    lo: float | None = None
    hi: float | None = None
    unit: str = ""

    def expected(self) -> str:
        """What the key takes, e.g. ``a whole number from 1 to 10000``."""
        span = (
            f" from {_num(self.lo)} to {_num(self.hi)}"
            if self.lo is not None and self.hi is not None
            else ""
        )
        unit = f" {self.unit}" if self.unit else ""
        return {
            "number": f"a number{span}{unit}",
            "int": f"a whole number{span}{unit}",
            "bool": "true or false",
            "vec3": f"a list of three numbers{span}{unit}",
            "fields": 'an object of sensor fields, e.g. {"gyro.arw_dpsh": 0.002}',
        }[self.kind]

    def describe(self, name: str) -> str:
        """``name=default: what it takes`` for the help text."""
        if self.default is _REQUIRED:
            head = f"{name} (required)"
        elif self.default is None:
            head = f"{name} (default: unchanged)"
        else:
            head = f"{name}={json.dumps(self.default)}"
        return f"{head}: {self.expected()}"

    def check(self, name: str, value: Any) -> Any:
        """The value as the op uses it, or :class:`ControlError` naming the key and the bound."""
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise ControlError(f"{name}: expected {self.expected()}, got {_show(value)}")
            return value
        if self.kind == "fields":
            if not isinstance(value, dict):
                raise ControlError(f"{name}: expected {self.expected()}, got {_show(value)}")
            return value
        if self.kind == "vec3":
            if not isinstance(value, list | tuple) or len(value) != 3:
                raise ControlError(f"{name}: expected {self.expected()}, got {_show(value)}")
            return tuple(self._scalar(f"{name}[{i}]", v, whole=False) for i, v in enumerate(value))
        return self._scalar(name, value, whole=self.kind == "int")

    def _scalar(self, name: str, value: Any, *, whole: bool) -> float | int:
        ok_type = isinstance(value, int) if whole else isinstance(value, int | float)
        # Python ints compare exactly with float bounds, so a 4000-digit integer is refused
        # here without being converted (which could overflow).
        if (
            isinstance(value, bool)
            or not ok_type
            or value != value  # NaN
            or (self.lo is not None and not self.lo <= value)
            or (self.hi is not None and not value <= self.hi)
            or value in (float("inf"), float("-inf"))
        ):
            raise ControlError(f"{name}: expected {self.expected()}, got {_show(value)}")
        return value if whole else float(value)


@dataclass(frozen=True)
class Op:
    """One operation of the control channel: what it does and the keys it takes."""

    help: str
    keys: Mapping[str, Key] = field(default_factory=dict)

    def usage(self, name: str) -> list[str]:
        """The op and its help, then one line per key (for ``simctl --help``)."""
        return [f"{name}: {self.help}", *(key.describe(k) for k, key in self.keys.items())]


_GYRO_DPH = 1e6  # beyond the range of any gyro preset (200 deg/s = 7.2e5 deg/h)
_ACCEL_UG = 1e7  # 10 g
_ON = Key("bool", True)

#: The operations and their keys: the controller checks every request against this table and
#: ``northfinder simctl --help`` prints it, so the two cannot disagree.
OPS: dict[str, Op] = {
    "status": Op("time, state, counters, speed and injected faults now"),
    "get_truth": Op("where the simulated instrument really stands"),
    "set_truth": Op(
        "move the simulated base; keys not given stay as they are",
        {
            "azimuth_deg": Key("number", None, -360.0, 360.0, "deg clockwise from north"),
            "latitude_deg": Key("number", None, -90.0, 90.0, "deg"),
            "pitch_deg": Key("number", None, -90.0, 90.0, "deg (the base stands at most 45)"),
            "roll_deg": Key("number", None, -90.0, 90.0, "deg (the base stands at most 45)"),
        },
    ),
    "get_sensor": Op("the sensor specification in datasheet units"),
    "set_sensor": Op("change sensor fields while running", {"values": Key("fields")}),
    "drop": Op("drop the next COUNT outgoing frames", {"count": Key("int", 1, 0, 100_000)}),
    "corrupt": Op("corrupt the next COUNT outgoing frames", {"count": Key("int", 1, 0, 100_000)}),
    "garble": Op(
        "put COUNT pieces of junk on the wire, PER_FRAME before each outgoing frame, which still "
        "goes out whole (SLCAN: a line that does not parse; serial: bytes of no frame; CAN: a "
        "frame of a wrong length)",
        {"count": Key("int", 1, 0, 1_000_000), "per_frame": Key("int", 1, 1, 16)},
    ),
    "delay_replies": Op(
        "send every reply SECONDS late (0 ends it)",
        {"seconds": Key("number", lo=0, hi=3600, unit="s")},
    ),
    "drop_replies": Op(
        "send no reply to the next COUNT commands (they are still carried out)",
        {"count": Key("int", 1, 0, 100_000)},
    ),
    "slow_heartbeat": Op(
        "send the heartbeat every HEARTBEAT_PERIOD_MS times FACTOR (1 ends it)",
        {"factor": Key("number", lo=0.1, hi=100.0)},
    ),
    "slow_stream": Op(
        "make each sample tick last FACTOR configured tick periods: the stream runs at "
        "SAMPLE_RATE_HZ / FACTOR (1 ends it)",
        {"factor": Key("number", lo=0.1, hi=100.0)},
    ),
    "silent": Op("stop sending anything (on=false ends it)", {"on": _ON}),
    "skip_counter": Op(
        "advance the sample counter by COUNT ticks once", {"count": Key("int", 1, 0, 1_000_000)}
    ),
    "wrong_result": Op(
        "the next reply carries result CODE and no data", {"code": Key("int", 7, 0, 255)}
    ),
    "stall": Op(
        "jam the table where it is; a move in progress ends in a DRIVE fault (on=false frees it)",
        {"on": _ON},
    ),
    "bias_step": Op(
        "add a permanent bias step from now",
        {
            "gyro_dph": Key("vec3", [0.0, 0.0, 0.0], -_GYRO_DPH, _GYRO_DPH, "deg/h"),
            "accel_ug": Key("vec3", [0.0, 0.0, 0.0], -_ACCEL_UG, _ACCEL_UG, "ug"),
        },
    ),
    "impulses": Op(
        f"a burst of COUNT half-sine shocks, one every INTERVAL_S, from now "
        f"(count x interval_s at most {MAX_BURST_S:g} s)",
        {
            "count": Key("int", 1, 1, 10_000),
            "interval_s": Key("number", 0.5, 0.01, 3600.0, "s"),
            "gyro_dph": Key("number", 50.0, 0.0, _GYRO_DPH, "deg/h peak"),
            "accel_ug": Key("number", 5000.0, 0.0, _ACCEL_UG, "ug peak"),
        },
    ),
    "vibration": Op(
        "switch vibration on or off (hz and amplitudes apply when the sensor has none)",
        {
            "on": _ON,
            "hz": Key("number", 35.0, 0.01, BASE_RATE_HZ / 2, "Hz"),
            "gyro_dph": Key("number", 5.0, 0.0, _GYRO_DPH, "deg/h"),
            "accel_ug": Key("number", 2000.0, 0.0, _ACCEL_UG, "ug"),
        },
    ),
    "reset": Op("restart the firmware as a watchdog would and clear injected faults"),
    "pause": Op("stop simulated time"),
    "resume": Op("let simulated time run again"),
    "speed": Op(
        "simulated seconds per wall second", {"value": Key("number", lo=0.001, hi=10_000.0)}
    ),
}


def check_request(request: Any) -> tuple[str, dict[str, Any]]:
    """``(op, arguments)`` of a request object, every argument checked and defaulted.

    Raises
    ------
    ControlError
        Not an object with a string ``op``, an unknown op or key (the message lists the right
        ones), or a value outside its bounds (the message states them).
    """
    if not isinstance(request, dict) or not isinstance(request.get("op"), str):
        raise ControlError('a request is a JSON object with a string "op"')
    name = request["op"]
    op = OPS.get(name)
    if op is None:
        raise ControlError(f"unknown op {_show(name)}; ops are {', '.join(sorted(OPS))}")
    unknown = sorted(set(request) - set(op.keys) - {"op"})
    if unknown:
        right = f"keys are {', '.join(op.keys)}" if op.keys else "it takes no keys"
        raise ControlError(f"{name}: unknown key {_show(unknown[0])}; {right}")
    args: dict[str, Any] = {}
    for key_name, key in op.keys.items():
        if key_name in request:
            try:
                args[key_name] = key.check(key_name, request[key_name])
            except ControlError as exc:
                raise ControlError(f"{name}: {exc}") from None
        elif key.default is _REQUIRED:
            raise ControlError(f"{name}: {key_name} is required: {key.expected()}")
        elif key.default is not None:
            args[key_name] = key.check(key_name, key.default)
    if name == "impulses" and args["count"] * args["interval_s"] > MAX_BURST_S:
        raise ControlError(
            f"impulses: count x interval_s = {args['count'] * args['interval_s']:g} s exceeds "
            f"the {MAX_BURST_S:g} s a burst may last"
        )
    return name, args


def parse_address(text: str) -> tuple[str, Any]:
    """``("tcp", (host, port))`` for ``HOST:PORT`` on loopback, ``("unix", path)`` otherwise.

    IPv6 hosts are written in brackets, ``[::1]:7700``. A port alone is on ``127.0.0.1``; port 0
    (``0``, ``HOST:0``) is any free port, chosen when the channel opens.

    Raises
    ------
    SimConfigError
        A TCP host that is not a loopback address: the channel must not be reachable from outside.
    """
    if text.startswith("unix:") or "/" in text:
        path = text.removeprefix("unix:")
        if not path:
            raise SimConfigError(f"control address {text!r}: expected unix:PATH")
        return "unix", path
    if text.strip().isdigit():
        text = f"127.0.0.1:{text.strip()}"
    host, sep, port = text.rpartition(":")
    if not sep:
        raise SimConfigError(f"control address {text!r}: expected HOST:PORT or unix:PATH")
    host = host.removeprefix("[").removesuffix("]") or "127.0.0.1"
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
            "drop": lambda a: self._set_fault("drop_frames", a["count"]),
            "corrupt": lambda a: self._set_fault("corrupt_frames", a["count"]),
            "garble": lambda a: self._set_faults(
                garble=a["count"], garble_per_frame=a["per_frame"]
            ),
            "delay_replies": lambda a: self._set_fault("reply_delay_s", a["seconds"]),
            "drop_replies": lambda a: self._set_fault("drop_replies", a["count"]),
            "slow_heartbeat": lambda a: self._set_fault("heartbeat_factor", a["factor"]),
            "slow_stream": lambda a: self._set_fault("tick_factor", a["factor"]),
            "silent": lambda a: self._set_fault("silent", a["on"]),
            "skip_counter": lambda a: self._set_fault("skip_counter", a["count"]),
            "wrong_result": lambda a: self._set_fault("wrong_result", a["code"]),
            "stall": lambda a: self._call(fw.stall_table, a["on"]),
            "bias_step": lambda a: self._call(
                fw.apply, lambda: fw.instrument.inject_bias_step(a["gyro_dph"], a["accel_ug"])
            ),
            "impulses": lambda a: self._call(fw.apply, lambda: fw.instrument.inject_impulses(**a)),
            "vibration": lambda a: self._call(fw.apply, lambda: fw.instrument.set_vibration(**a)),
            "reset": lambda a: self._call(self._reset),
            "pause": lambda a: self._call(runner.pause),
            "resume": lambda a: self._call(runner.resume),
            "speed": lambda a: self._call(runner.set_speed, a["value"]),
        }
        assert set(self._ops) == set(OPS), "every op in the table has an implementation"

    @property
    def ops(self) -> list[str]:
        return sorted(self._ops)

    def handle(self, request: Any) -> dict[str, Any]:
        """Check and carry out one request object; always returns a reply object."""
        try:
            op, args = check_request(request)
        except ControlError as exc:
            return {"ok": False, "error": str(exc)}
        try:
            with self.runner.lock:
                return {"ok": True, **self._ops[op](args)}
        except (SimError, ValueError, TypeError) as exc:
            return {"ok": False, "error": f"{op}: {exc}"}
        finally:
            self.runner.changed()

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
            "speed": self.runner.speed,
            "paused": self.runner.paused,
            "clock": "virtual" if self.runner.virtual else "paced",
            "lag": dataclasses.asdict(self.runner.lag),
            "sender": self.runner.sender_info(),
            "faults": dataclasses.asdict(fw.faults),
        }

    def _set_truth(self, args: dict[str, Any]) -> dict[str, Any]:
        fw = self.runner.firmware
        truth = dataclasses.replace(fw.instrument.truth, **args)  # Truth checks the whole
        fw.set_truth(truth)
        return {"truth": dataclasses.asdict(truth)}

    def _set_sensor(self, args: dict[str, Any]) -> dict[str, Any]:
        fw = self.runner.firmware
        spec = fw.instrument.spec.with_values(args["values"])
        fw.set_spec(spec)  # refuses, unchanged, what the device cannot run
        return {"sensor": spec.to_dict()}

    def _set_fault(self, name: str, value: Any) -> dict[str, Any]:
        faults = self.runner.firmware.faults
        self.runner.firmware.apply(lambda: setattr(faults, name, value))
        return {"faults": dataclasses.asdict(self.runner.firmware.faults)}

    def _set_faults(self, **values: Any) -> dict[str, Any]:
        faults = self.runner.firmware.faults

        def set_all() -> None:
            for k, v in values.items():
                setattr(faults, k, v)

        self.runner.firmware.apply(set_all)
        return {"faults": dataclasses.asdict(self.runner.firmware.faults)}

    def _reset(self) -> None:
        fw = self.runner.firmware
        fw.apply(lambda: fw.instrument.table.stall(fw.now, False))
        fw.faults = type(fw.faults)()
        fw.reboot()


def _reply_line(reply: dict[str, Any]) -> bytes:
    """One JSON line, also for a reply that JSON cannot carry (then an error says so)."""
    try:
        text = json.dumps(reply, allow_nan=False)
    except (TypeError, ValueError) as exc:
        text = json.dumps({"ok": False, "error": f"reply not representable in JSON: {exc}"})
    return text.encode() + b"\n"


class _Handler(socketserver.StreamRequestHandler):
    server: _TcpServer | _UnixServer

    def handle(self) -> None:
        try:
            while self._one_line():
                pass
        except OSError:
            pass  # the client went away; nothing to answer

    def _one_line(self) -> bool:
        """Read, answer one request line; False at the end of the connection."""
        raw = self.rfile.readline(MAX_LINE_BYTES + 1)  # the longest line and its newline
        if not raw:
            return False
        if len(raw.removesuffix(b"\n")) > MAX_LINE_BYTES:
            error = f"request line longer than {MAX_LINE_BYTES} bytes"
            self.wfile.write(_reply_line({"ok": False, "error": error}))
            while raw and not raw.endswith(b"\n"):  # skip the rest of it, never holding more
                raw = self.rfile.readline(MAX_LINE_BYTES + 1)
            return bool(raw)
        try:
            request = json.loads(raw)
        except RecursionError:
            reply: dict[str, Any] = {"ok": False, "error": "not a JSON line: nested too deeply"}
        except ValueError as exc:  # also a too long integer, and bytes that are not UTF-8
            reply = {"ok": False, "error": f"not a JSON line: {_show(str(exc), 120)}"}
        else:
            try:
                reply = self.server.controller.handle(request)
            except Exception as exc:  # a bug must cost one reply, not the channel
                log.exception("control request failed")
                reply = {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}
        self.wfile.write(_reply_line(reply))
        return True


class _Quiet:
    """Errors of one connection are logged in one line, never printed as a traceback."""

    def handle_error(self, request: Any, client_address: Any) -> None:
        log.warning("control connection %s ended with an error", client_address, exc_info=False)


class _TcpServer(_Quiet, socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    controller: Controller


class _Tcp6Server(_TcpServer):
    address_family = socket.AF_INET6


class _UnixServer(_Quiet, socketserver.ThreadingUnixStreamServer):
    daemon_threads = True
    controller: Controller


def _claim_unix_path(path: str) -> None:
    """Make ``path`` free for a new socket: only a stale socket (nobody listening) is removed.

    Raises
    ------
    SimConfigError
        The path is something else than a socket, or a process listens on it.
    """
    where = f"control address unix:{path}"
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise SimConfigError(f"{where}: cannot inspect the path ({exc.strerror})") from exc
    if not stat.S_ISSOCK(mode):
        raise SimConfigError(f"{where}: the path exists and is not a socket; choose another path")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(path)
    except ConnectionRefusedError:
        os.unlink(path)  # a socket left behind by a process that has ended
        return
    except OSError as exc:
        raise SimConfigError(f"{where}: cannot tell whether the socket is in use ({exc})") from exc
    finally:
        probe.close()
    raise SimConfigError(f"{where}: another process is listening on that socket")


class ControlServer:
    """Serves a :class:`Controller` on a loopback TCP address or a Unix socket, in a thread.

    Raises
    ------
    SimConfigError
        A bad address, a path that exists and is not a stale socket, or an address it cannot
        listen on (in use, no IPv6); one line naming the address.
    """

    def __init__(self, controller: Controller, address: str) -> None:
        kind, addr = parse_address(address)
        self._inode: int | None = None
        try:
            if kind == "unix":
                _claim_unix_path(addr)
                self._server: _TcpServer | _UnixServer = _UnixServer(addr, _Handler)
                self._inode = os.stat(addr).st_ino
            else:
                ipv6 = ":" in addr[0]
                self._server = (_Tcp6Server if ipv6 else _TcpServer)(addr, _Handler)
        except OSError as exc:
            raise SimConfigError(
                f"control address {address}: cannot listen there ({exc.strerror or exc})"
            ) from exc
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
            return f"[{host}]:{address[1]}" if ":" in host else f"{host}:{address[1]}"
        return f"unix:{os.fsdecode(address) if isinstance(address, str | bytes) else address!r}"

    def start(self) -> ControlServer:
        self._thread.start()
        return self

    def __enter__(self) -> ControlServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._thread.is_alive():  # shutdown() waits for a serve loop that never started
            self._server.shutdown()
        self._server.server_close()
        address = self._server.server_address
        if self.kind == "unix" and isinstance(address, str | bytes):
            try:
                if os.stat(address).st_ino == self._inode:  # ours, not a successor's
                    os.unlink(address)
            except OSError:
                pass


class ControlClient:
    """A small blocking client: ``client.call("drop", count=5)`` returns the reply object.

    Raises
    ------
    ControlRefused
        The simulator answered ``ok: false`` (its message is kept).
    ControlError
        The channel cannot be reached or did not answer in time.
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
        self._address, self._timeout = address, timeout

    def call(self, op: str, **args: Any) -> dict[str, Any]:
        try:
            self._file.write(json.dumps({"op": op, **args}).encode() + b"\n")
            self._file.flush()
            line = self._file.readline(4 * MAX_LINE_BYTES)
        except TimeoutError as exc:
            raise ControlError(
                f"no reply from the control channel at {self._address} within {self._timeout:g} s"
            ) from exc
        except OSError as exc:
            raise ControlError(f"control channel: {exc}") from exc
        if not line:
            raise ControlError("control channel closed by the simulator")
        try:
            reply = json.loads(line)
        except ValueError as exc:
            raise ControlError(f"control channel: the reply is not a JSON line ({exc})") from exc
        if not isinstance(reply, dict) or not reply.get("ok"):
            error = reply.get("error") if isinstance(reply, dict) else None
            raise ControlRefused(error or "request refused")
        return reply

    def close(self) -> None:
        self._file.close()
        self._sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
