"""SocketCAN smoke test: paced frames from one bus to another over a (virtual) CAN interface.

The sender runs in this process; the receiver runs in a child process (its own bus, its own
CPU), and ``candump -L`` records the traffic to a file. Every frame carries a sequence number,
so the receiver counts lost, duplicated and reordered frames. Inter-arrival jitter comes from
the kernel receive timestamps.

    python smoke_can.py --out DIR [--channel vcan0] [--rate 800] [--frames 4000]

Writes DIR/result.json and DIR/candump.log; exits 0 when every frame arrived, 1 otherwise.
Uses only python-can and the standard library (imports are slow under software emulation).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time

DATA_ID = 0x123
END_ID = 0x7FF
PAYLOAD = struct.Struct("<II")  # sequence number, sender perf_counter in microseconds (low 32 bits)


def percentile(sorted_values: list[float], q: float) -> float | None:
    """Nearest-rank percentile of an already sorted list."""
    if not sorted_values:
        return None
    k = max(0, min(len(sorted_values) - 1, round(q / 100 * (len(sorted_values) - 1))))
    return sorted_values[k]


def stats_us(values_s: list[float]) -> dict:
    v = sorted(values_s)
    us = lambda x: None if x is None else round(x * 1e6, 1)  # noqa: E731
    return {
        "n": len(v),
        "p50_us": us(percentile(v, 50)),
        "p99_us": us(percentile(v, 99)),
        "max_us": us(v[-1] if v else None),
    }


def open_bus(channel: str):
    import can

    return can.Bus(interface="socketcan", channel=channel, receive_own_messages=False)


def set_rcvbuf(sock: socket.socket, size: int) -> int:
    """Ask for a receive buffer of ``size`` bytes; return what the kernel granted.

    A CAN frame takes about 1 KiB of socket buffer, so the default (about 200 KiB) holds only a
    fraction of a second at 800 frames/s: enough when the receiver keeps up, not when a loaded
    machine stalls the (emulated) guest. SO_RCVBUFFORCE (root) goes beyond net.core.rmem_max.
    """
    if size > 0:
        for opt in (getattr(socket, "SO_RCVBUFFORCE", 33), socket.SO_RCVBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, size)
                break
            except OSError:
                continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def receiver(args) -> int:
    """Child process: receive until the end frame (or a deadline), print one JSON line."""
    bus = open_bus(args.channel)
    rcvbuf = set_rcvbuf(bus.socket, args.rcvbuf)
    print(json.dumps({"ready": True, "rcvbuf": rcvbuf}), flush=True)
    seqs: list[int] = []
    stamps: list[float] = []
    end_seen = False
    deadline = time.monotonic() + args.rx_deadline
    while True:
        msg = bus.recv(timeout=1.0)
        # The deadline is looked at when the bus is quiet and every 1024 frames, not per frame:
        # a clock read is a system call, and those are dear under user-mode Linux.
        if (msg is None or len(seqs) % 1024 == 1023) and time.monotonic() >= deadline:
            break
        if msg is None:
            continue
        if msg.arbitration_id == END_ID:
            end_seen = True
            break
        if msg.arbitration_id != DATA_ID or len(msg.data) != PAYLOAD.size:
            continue
        seqs.append(PAYLOAD.unpack(bytes(msg.data))[0])
        stamps.append(msg.timestamp)
    bus.shutdown()

    unique = set(seqs)
    out_of_order = sum(1 for a, b in itertools.pairwise(seqs) if b < a)
    period = 1.0 / args.rate
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    print(
        json.dumps(
            {
                "received": len(seqs),
                "unique": len(unique),
                "duplicates": len(seqs) - len(unique),
                "out_of_order": out_of_order,
                "missing_seqs_head": sorted(set(range(args.frames)) - unique)[:20],
                "end_seen": end_seen,
                "interarrival": stats_us(gaps),
                "jitter": stats_us([abs(g - period) for g in gaps]),
                "rcvbuf": rcvbuf,
            }
        ),
        flush=True,
    )
    return 0


def start_candump(channel: str, path: str, rcvbuf: int):
    """Start ``candump -L`` and wait until it holds a socket (so it sees the first frame)."""
    exe = shutil.which("candump")
    if exe is None:
        return None, "candump not found"
    cmd = [exe, "-L", *(["-r", str(rcvbuf)] if rcvbuf > 0 else []), channel]
    # The children keep their own copies of the descriptors.
    with open(path, "wb") as f, open(path + ".err", "wb") as err:
        proc = subprocess.Popen(cmd, stdout=f, stderr=err)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return None, f"candump exited with {proc.returncode}"
        try:
            fds = os.listdir(f"/proc/{proc.pid}/fd")
            if any(os.readlink(f"/proc/{proc.pid}/fd/{fd}").startswith("socket:") for fd in fds):
                time.sleep(0.2)  # socket() is followed by bind(); give it a moment
                return proc, None
        except OSError:
            pass
        time.sleep(0.05)
    return proc, "candump did not open a socket within 20 s"


def stop_candump(proc, path: str) -> int | None:
    if proc is None:
        return None
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    with open(path, "rb") as f:
        return sum(1 for line in f if line.startswith(b"("))


def sender(args) -> int:
    os.makedirs(args.out, exist_ok=True)
    result: dict = {
        "step": "smoke",
        "channel": args.channel,
        "rate_hz": args.rate,
        "frames_planned": args.frames,
        "rcvbuf_requested": args.rcvbuf,
    }
    t_start = time.monotonic()
    candump_path = os.path.join(args.out, "candump.log")
    dump, dump_err = start_candump(args.channel, candump_path, args.rcvbuf)
    if dump_err:
        result["candump_error"] = dump_err

    rx = subprocess.Popen(
        [sys.executable, os.path.abspath(__file__), "--role", "rx", *args.passthrough],
        stdout=subprocess.PIPE,
        text=True,
    )
    ready_line = ""
    r, _, _ = select.select([rx.stdout], [], [], 120)
    if r:
        ready_line = rx.stdout.readline()
    if '"ready"' not in ready_line:
        rx.kill()
        result.update(ok=False, error=f"receiver did not start: {ready_line!r}")
        return finish(args, result, dump, candump_path, t_start)

    import can

    bus = open_bus(args.channel)
    period = 1.0 / args.rate
    sent = 0
    send_errors = 0
    lateness: list[float] = []
    # One clock read per late frame, and a plain send (no writability select): where every
    # system call is expensive (user-mode Linux: each one is a round trip through the tracing
    # kernel) the sender's own calls decide whether it holds the rate. A frame that is due goes
    # out at once; the loop sleeps (and reads the clock again) only when it is ahead.
    clock = time.perf_counter
    t0 = clock() + 0.05
    for seq in range(args.frames):
        due = t0 + seq * period
        now = clock()
        if due > now:
            time.sleep(due - now)
            now = clock()
        lateness.append(max(0.0, now - due))
        msg = can.Message(
            arbitration_id=DATA_ID,
            is_extended_id=False,
            data=PAYLOAD.pack(seq, int(now * 1e6) & 0xFFFFFFFF),
        )
        for _attempt in range(50):
            try:
                bus.send(msg)
                sent += 1
                break
            except can.CanError:  # transmit queue full: let the receivers drain it
                send_errors += 1
                time.sleep(0.001)
    elapsed = clock() - t0
    time.sleep(0.2)
    bus.send(can.Message(arbitration_id=END_ID, is_extended_id=False, data=b"\x00"))
    bus.shutdown()

    try:
        rx_out, _ = rx.communicate(timeout=args.rx_deadline + 30)
    except subprocess.TimeoutExpired:
        rx.kill()
        rx_out, _ = rx.communicate()
    rx_result = {}
    for line in rx_out.splitlines():
        if line.startswith("{") and '"received"' in line:
            rx_result = json.loads(line)
    received = rx_result.get("unique", 0)
    result.update(
        frames_sent=sent,
        frames_received=received,
        frames_lost=sent - received,
        send_errors=send_errors,
        send_seconds=round(elapsed, 3),
        achieved_rate_hz=round(sent / elapsed, 1) if elapsed > 0 else None,
        sender_lateness=stats_us(lateness),
        receiver=rx_result,
    )
    # Informational: under software emulation on a loaded machine the sender may fall behind.
    result["rate_reached"] = sent == 0 or elapsed <= args.frames / args.rate * 1.05
    result["ok"] = (
        bool(rx_result)
        and sent == args.frames
        and received == sent
        and rx_result.get("duplicates", 1) == 0
        and rx_result.get("end_seen", False)
    )
    return finish(args, result, dump, candump_path, t_start)


def finish(args, result: dict, dump, candump_path: str, t_start: float) -> int:
    count = stop_candump(dump, candump_path)
    if count is not None:
        # candump sees the data frames plus the end frame.
        result["candump_frames"] = count
        result["candump_data_frames"] = count - (
            1 if result.get("receiver", {}).get("end_seen") else 0
        )
        result["candump_file"] = candump_path
        if (
            result.get("frames_sent") is not None
            and result["candump_data_frames"] != result["frames_sent"]
        ):
            result["ok"] = False
            result["candump_mismatch"] = True
    else:
        result["ok"] = False
    result["step_seconds"] = round(time.monotonic() - t_start, 3)
    with open(os.path.join(args.out, "result.json"), "w") as f:
        json.dump(result, f, indent=2)
        f.write("\n")
    rx = result.get("receiver", {})
    print(
        f"smoke: sent {result.get('frames_sent')} received {result.get('frames_received')} "
        f"lost {result.get('frames_lost')} candump {result.get('candump_data_frames')} "
        f"rate {result.get('achieved_rate_hz')} Hz "
        f"jitter p50 {rx.get('jitter', {}).get('p50_us')} us p99 {rx.get('jitter', {}).get('p99_us')} us "
        f"-> {'PASS' if result['ok'] else 'FAIL'}"
    )
    return 0 if result["ok"] else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--role", choices=["tx", "rx"], default="tx")
    p.add_argument("--out", default=".")
    p.add_argument("--channel", default=os.environ.get("HIL_CAN_IF", "vcan0"))
    p.add_argument("--rate", type=float, default=800.0)
    p.add_argument("--frames", type=int, default=4000)
    p.add_argument(
        "--rcvbuf",
        type=int,
        default=8 << 20,
        help="receive buffer to ask for, bytes, for the receiver and candump (0: system default)",
    )
    args = p.parse_args(argv)
    args.rx_deadline = args.frames / args.rate * 10 + 60
    args.passthrough = [
        "--rcvbuf",
        str(args.rcvbuf),
        "--channel",
        args.channel,
        "--rate",
        str(args.rate),
        "--frames",
        str(args.frames),
    ]
    return receiver(args) if args.role == "rx" else sender(args)


if __name__ == "__main__":
    sys.exit(main())
