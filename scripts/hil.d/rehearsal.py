"""HIL step "rehearsal": the simulator and the host as separate processes on a real SocketCAN bus.

1. ``candump -L`` records all traffic on the interface.
2. ``northfinder sim -i socketcan -c IF`` runs as its own process (real time).
3. ``northfinder find -i socketcan -c IF --json`` finds north against it; the result is checked
   against the simulator's truth (within 5 sigma and 0.5 deg).
4. ``northfinder conformance -i socketcan -c IF --junit ...`` checks the unit against protocol.md.
5. The candump log is decoded with cantools against protocol.dbc: every frame known, sample
   ticks contiguous within each stream burst, cycle times of samples and heartbeats measured.

Writes ``result.json`` (frames seen, frames lost, cycle jitter p50/p99, azimuth error) and exits
non-zero when any part fails.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

TRUTH = {"azimuth": 123.456, "latitude": 34.0, "pitch": 1.5, "roll": -0.8}


#: Conformance checks that time the unit against the host's wall clock.
TIMING_SENSITIVE = frozenset(
    {"heartbeat.period", "heartbeat.jitter", "stream.rate", "timing.reply", "rotation.settle_time",
     "command.stop_while_rotating", "command.set_config", "command.stream_start"}
)  # fmt: skip


def junit_failures(path: Path) -> set[str]:
    """Names of the failed checks in the suite's JUnit XML (empty if the file is missing)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return {"<no JUnit report>"}
    return {tc.get("name", "?") for tc in root.iter("testcase") if tc.find("failure") is not None}


def start(cmd: list[str], log: Path, **kw) -> subprocess.Popen:
    fh = log.open("w")
    return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True, **kw)


def stop(proc: subprocess.Popen, timeout: float = 20.0) -> int | None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
    return proc.returncode


def percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    s = sorted(values)
    return s[min(len(s) - 1, round(q / 100.0 * (len(s) - 1)))]


def analyse_candump(path: Path, dbc: Path, bad_input_from: float) -> dict:
    """Decode every frame with cantools; tick continuity and cycle times of the stream.

    From ``bad_input_from`` (epoch seconds) on, the conformance suite puts malformed and foreign
    frames on the bus on purpose: from then on only the device's own frames must all decode.
    """
    import cantools

    from northfinder.driver.protocol.constants import Opcode

    db = cantools.database.load_file(str(dbc))
    known = {m.frame_id for m in db.messages}
    frames = unknown = undecodable = deliberate = undefined_echo = 0
    opcodes = {int(op) for op in Opcode}
    aux_times: list[float] = []
    aux_ticks: list[int] = []
    status_times: list[float] = []
    for line in path.read_text(errors="replace").splitlines():
        parts = line.split()
        if len(parts) < 3 or "#" not in parts[2]:
            continue
        t = float(parts[0].strip("()"))
        can_id, _, data = parts[2].partition("#")
        arb, payload = int(can_id, 16), bytes.fromhex(data)
        frames += 1
        from_host = arb not in known or arb & 0x7F0 == 0x040
        if t >= bad_input_from and from_host:
            deliberate += 1
            continue
        if arb not in known:
            unknown += 1
            continue
        if arb & 0x7F0 == 0x050 and len(payload) >= 2 and payload[1] not in opcodes:
            # A reply echoing an undefined opcode (the answer to the conformance suite's bad
            # input): the DBC multiplexes replies on the opcode, so cantools cannot name it.
            undefined_echo += 1
            continue
        try:
            decoded = db.decode_message(arb, payload, decode_choices=False, allow_truncated=True)
        except Exception:
            undecodable += 1
            continue
        if arb == 0x131:
            aux_times.append(t)
            aux_ticks.append(int(next(v for k, v in decoded.items() if "tick" in k.lower())))
        elif arb == 0x201:
            status_times.append(t)
    # Streams run in bursts (one per window); a pause longer than 0.5 s starts a new burst, in
    # which the tick must advance by one each time.
    lost, sample_periods = 0, []
    for i in range(1, len(aux_ticks)):
        dt = aux_times[i] - aux_times[i - 1]
        if dt > 0.5:
            continue
        gap = (aux_ticks[i] - aux_ticks[i - 1]) & 0xFF
        lost += gap - 1 if gap else 255
        sample_periods.append(dt)
    hb = [b - a for a, b in itertools.pairwise(status_times) if b - a < 1.0]
    return {
        "frames": frames,
        "unknown_frames": unknown,
        "undecodable_frames": undecodable,
        "conformance_bad_input_frames": deliberate,
        "replies_to_undefined_opcodes": undefined_echo,
        "sample_ticks": len(aux_ticks),
        "ticks_lost": lost,
        "sample_period_ms_p50": 1e3 * percentile(sample_periods, 50),
        "sample_jitter_ms_p50": 1e3 * percentile([abs(p - 0.005) for p in sample_periods], 50),
        "sample_jitter_ms_p99": 1e3 * percentile([abs(p - 0.005) for p in sample_periods], 99),
        "sample_period_ms_mean": 1e3 * sum(sample_periods) / len(sample_periods)
        if sample_periods
        else math.nan,
        "heartbeats": len(status_times),
        "heartbeat_period_ms_p50": 1e3 * percentile(hb, 50),
        "heartbeat_jitter_ms_p99": 1e3 * percentile([abs(p - 0.1) for p in hb], 99),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--repo", type=Path, required=True)
    ap.add_argument("--stream-seconds", type=float, default=30.0)
    args = ap.parse_args()
    out: Path = args.out
    bindir = Path(sys.executable).parent
    nf = str(bindir / "northfinder")
    ch = args.channel
    result: dict = {"channel": ch}
    failures: list[str] = []
    candump = shutil.which("candump")
    dump = start([candump, "-L", "-r", "8388608", ch], out / "candump.log") if candump else None
    sim = start(
        [nf, "sim", "-i", "socketcan", "-c", ch, "--warmup", "0", "--sensor", "nav-fog", "--seed", "7",
         "--azimuth", str(TRUTH["azimuth"]), "--latitude", str(TRUTH["latitude"]),
         "--pitch", str(TRUTH["pitch"]), "--roll", str(TRUTH["roll"])],
        out / "sim.log",
    )  # fmt: skip
    conformance_start = math.inf
    try:
        time.sleep(3.0)  # the simulator boots (the interpreter starts slowly under emulation)
        t0 = time.monotonic()
        find = subprocess.run(
            [nf, "find", "-i", "socketcan", "-c", ch, "--json", "--latitude", str(TRUTH["latitude"]),
             "--link-timeout", "3", "--reply-timeout", "2", "--timeout", "300", "--record", str(out / "windows.npz")],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        result["find_wall_s"] = round(time.monotonic() - t0, 1)
        (out / "find.json").write_text(find.stdout)
        (out / "find.err").write_text(find.stderr)
        if find.returncode != 0:
            failures.append(f"find exited {find.returncode}: {find.stderr.strip()[-300:]}")
        else:
            res = json.loads(find.stdout)
            err = (res["azimuth_deg"] - TRUTH["azimuth"] + 180.0) % 360.0 - 180.0
            result.update(
                azimuth_deg=res["azimuth_deg"], truth_deg=TRUTH["azimuth"], azimuth_error_deg=err,
                sigma_deg=res["sigma_deg"], pitch_deg=res["pitch_deg"], roll_deg=res["roll_deg"],
            )  # fmt: skip
            if not abs(err) <= min(0.5, 5.0 * res["sigma_deg"]):
                failures.append(
                    f"azimuth error {err:+.4f} deg exceeds 5 sigma ({res['sigma_deg']:.4f})"
                )
        conformance_start = time.time()
        # Under software emulation the interpreters run about 18 times slower and stall for
        # hundreds of milliseconds: host-side timing at millisecond scale means nothing there, so
        # its margins are wide in a VM (and recorded); every logical check stays as strict.
        relaxed = os.environ.get("HIL_MODE") == "vm"
        timing = ["--reply-limit-ms", "2000", "--jitter-margin-ms", "1000", "--rate-tolerance", "0.05",
                  "--settle-margin", "5", "--ready-timeout", "300"] if relaxed else []  # fmt: skip
        result["conformance_timing"] = (
            "relaxed for software emulation: " + " ".join(timing)
            if relaxed
            else "protocol defaults"
        )
        conf = subprocess.run(
            [nf, "conformance", "-i", "socketcan", "-c", ch, "--stream-seconds", str(args.stream_seconds),
             "--junit", str(out / "conformance.xml"), *timing],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        (out / "conformance.txt").write_text(conf.stdout + conf.stderr)
        result["conformance_exit"] = conf.returncode
        last = [line for line in conf.stdout.splitlines() if "passed" in line]
        result["conformance"] = last[-1].strip() if last else conf.stderr.strip()[-300:]
        failed = junit_failures(out / "conformance.xml")
        if relaxed:
            # Checks that time the unit against the host's wall clock: an emulated host that runs
            # 18 times slower and stalls cannot judge them; they are reported, not counted.
            result["timing_failures_under_emulation"] = sorted(failed & TIMING_SENSITIVE)
            failed -= TIMING_SENSITIVE
        if conf.returncode not in (0, 1) or failed:
            failures.append(f"conformance: {sorted(failed) or result['conformance']}")
    finally:
        result["sim_exit"] = stop(sim)
        if dump is not None:
            stop(dump)
    if dump is None:
        failures.append("candump (can-utils) not found: traffic not recorded")
    else:
        stats = analyse_candump(out / "candump.log", args.repo / "protocol.dbc", conformance_start)
        result.update(stats)
        if stats["unknown_frames"] or stats["undecodable_frames"]:
            failures.append(
                f"{stats['unknown_frames']} unknown and {stats['undecodable_frames']} undecodable frames"
            )
        if stats["ticks_lost"]:
            failures.append(f"{stats['ticks_lost']} sample ticks lost on the bus")
        # The cycle times on the bus are the unit's timing. Under emulation the simulator's
        # interpreter falls behind real time whenever the machine is busy, so there they are
        # reported (pace_under_emulation), not counted; on a host with vcan0 they count.
        pace = []
        if not abs(stats["sample_period_ms_mean"] - 5.0) <= 0.05:
            pace.append(
                f"mean sample period {stats['sample_period_ms_mean']:.3f} ms, not 5 ms +- 1 %"
            )
        if not abs(stats["heartbeat_period_ms_p50"] - 100.0) <= 10.0:
            pace.append(
                f"median heartbeat period {stats['heartbeat_period_ms_p50']:.1f} ms, not 100 ms +- 10 %"
            )
        if os.environ.get("HIL_MODE") == "vm":
            result["pace_under_emulation"] = pace or "on time"
        else:
            failures += pace
    result["failures"] = failures
    (out / "result.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
