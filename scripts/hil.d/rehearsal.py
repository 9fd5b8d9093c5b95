"""HIL step "rehearsal": the simulator and the host as separate processes on a real SocketCAN bus.

1. ``candump -L`` records all traffic on the interface.
2. ``northfinder sim -i socketcan -c IF`` runs as its own process (real time).
3. ``northfinder find -i socketcan -c IF --json`` finds north against it; the result is checked
   against the simulator's truth (within 5 sigma and 0.5 deg).
3b. ``northfinder find -i socketcan -c IF --json --spin 6`` finds north on the turning table
   (protocol 1.1, one whole turn): within 5 sigma and 0.5 deg of the truth, and a sigma no
   lower than the white-noise bound of the spin (``judge_spin``).
4. ``northfinder conformance -i socketcan -c IF --junit ...`` checks the unit against protocol.md.
4b. ``northfinder accept -i socketcan -c IF --datasheet ...`` tests the unit against a datasheet
   (``ACCEPT_DATASHEET``: a minute still, two runs of 0,180): every stage over the bus; a line
   that FAILs counts, NOT RESOLVED (exit 4: two runs decide little) does not.
5. The candump log is decoded with cantools against protocol.dbc: every frame known, sample
   ticks contiguous within each stream burst, cycle times of samples and heartbeats measured.

How strict depends on where it runs (``--mode``, default ``$HIL_MODE``); see ``REPORT_ONLY``:
on a host with vcan0 and under user-mode Linux every check counts except the ones listed for
that mode, which are run, reported with their reason, and not counted.

Writes ``result.json`` (azimuth error; the spin find's error, sigma and bound; frames, lost
ticks, arrival jitter p50/p99, conformance counted/passed, guest CPU use, the verdict). Exit
status: 0 every counted part held; 1 a counted part failed; 3 not judged: parts failed the way a
starved VM fails them, and the VM was measured unable to carry a real-time instrument (see
``judge``; the reasons are printed and in ``not_judged_because``). A wrong heading, a sigma below
the physical bound, an unknown or undecodable frame, a hang, a missing report, an internal error,
a wrong conformance answer or a simulator that died always fails. Reaches the product only
through the ``northfinder`` command line, python-can's SocketCAN (through candump) and cantools.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TRUTH = {"azimuth": 123.456, "latitude": 34.0, "pitch": 1.5, "roll": -0.8}
#: The simulator's sensor, and its gyro angle random walk (deg/sqrt(h); the preset's own figure,
#: checked by tests/test_hil_scripts.py): the white-noise bound of the spin find.
SENSOR = "nav-fog"
SENSOR_ARW_DPSH = 0.002
#: The spin find (protocol 1.1): table rate, deg/s; its default spin time is the fewest whole
#: turns lasting 60 s (one turn at 6 deg/s).
SPIN_RATE_DPS = 6.0
#: The spin's reported sigma may fall this far below the white-noise bound (the sigma is itself
#: estimated from the residuals: about 0.5 % scatter over one turn at 200 Hz); further below, the
#: result claims more than the physics allows, which is a bug.
SPIN_SIGMA_FLOOR = 0.95
EARTH_RATE_RPS = 7.292115e-5

#: Conformance checks that time the unit against the host's wall clock.
TIMING_SENSITIVE = frozenset(
    {"heartbeat.period", "heartbeat.jitter", "stream.rate", "timing.reply", "rotation.settle_time",
     "command.stop_while_rotating", "command.set_config", "command.stream_start"}
)  # fmt: skip

_QEMU = (
    "QEMU software emulation: the interpreters run about 18 times slower and stall for hundreds "
    "of milliseconds, so the host's wall clock cannot judge millisecond timing"
)
_UML_ONE_CPU = (
    "user-mode Linux: one guest CPU carries the instrument, the host and candump, and every "
    "system call (clock reads included) is a round trip of 15 to 70 us through the tracing kernel"
)
#: Measured under user-mode Linux (BENCHMARKS.md, Hardware in the loop). The timing checks that
#: held in every run, idle and with two CPU-bound processes beside the VM
#: (command.stop_while_rotating, the median heartbeat period on the bus) count.
_UML = {
    "heartbeat.jitter": _UML_ONE_CPU
    + "; single heartbeats leave 26 to 117 ms off their period in every run, idle or loaded",
    "timing.reply": _UML_ONE_CPU
    + "; the median reply takes 17 to 21 ms, but a few exceed 100 ms (up to 0.45 s) in about "
    "half the runs",
    "command.stream_start": _UML_ONE_CPU
    + "; the first sample came 278 ms after the reply in 2 of 12 runs on a loaded machine (1 to "
    "5 ms otherwise)",
    "command.set_config": _UML_ONE_CPU
    + "; on a loaded machine the guest stalls (up to 0.3 s when a process starts or ends) and "
    "the rate set came out 97.8 Hz for 100 in 1 of 12 runs",
    "pace.sample_period": _UML_ONE_CPU
    + "; on a loaded machine the stream fell behind during find in 2 of 12 runs (mean period "
    "5.10 and 5.73 ms)",
    **{
        name: _UML_ONE_CPU + "; held in 11 of 12 runs; in one, at load 12 with two CPU-bound "
        "processes beside the VM, the guest saturated and the simulator ran behind and caught up "
        "(heartbeat period 94.0 ms, sample rate 207.8 Hz over the window)"
        for name in ("stream.rate", "heartbeat.period")
    },
    "rotation.settle_time": _UML_ONE_CPU
    + "; on a loaded machine the simulator fell behind real time during a move in 2 of 12 runs "
    "(READY after 14.0 s, allowed 11.2 s)",
}

#: Measured again with the simulator's one-system-call SocketCAN sends, the host's batched reads
#: and the simulator's precedence inside the guest (BENCHMARKS.md, Hardware in the loop).
_UML_SINCE = (
    "; since the simulator sends with one system call a frame and runs at nice -10 in the guest, "
    "it held in 9 of 9 runs at load 1 to 5.5, but it stays reported: a CI machine measured system "
    "calls about twice as dear (SocketCAN send 0.55 ms, against 0.22 to 0.31 ms in those runs)"
)
_UML = {
    name: why + ("" if name == "heartbeat.jitter" else _UML_SINCE) for name, why in _UML.items()
}
_UML["heartbeat.jitter"] += "; since the changes, single intervals 85 to 206 ms in 3 of 9 runs"

#: Per mode: conformance checks (and the rehearsal's own "pace" checks of the cycle times on
#: the bus) that are run and reported with the reason, but not counted. Everything else counts.
REPORT_ONLY: dict[str, dict[str, str]] = {
    "direct": {},
    "uml": _UML,
    "qemu": {
        name: _QEMU for name in (*TIMING_SENSITIVE, "pace.sample_period", "pace.heartbeat_period")
    },
}

#: Wider conformance margins per mode (the protocol's defaults where absent).
CONFORMANCE_MARGINS: dict[str, list[str]] = {
    "qemu": ["--reply-limit-ms", "2000", "--jitter-margin-ms", "1000", "--rate-tolerance", "0.05",
             "--settle-margin", "5", "--ready-timeout", "300"],
}  # fmt: skip


#: When a rehearsal that failed is "not judged" (exit 3) instead of failed (exit 1), under
#: user-mode Linux only: the VM could not carry a real-time instrument, which both of these show,
#: and no failure of the never-excused kind (``hard`` in main: a wrong heading, an unknown or
#: undecodable frame, a hang, a missing report, an internal error, a simulator that died, an
#: answer that is wrong rather than missing) occurred.
#: 1. The instrument lost real time: the simulator (given precedence in the guest) fell behind its
#:    clock by LOST_REAL_TIME_S or more in all (its own count, in its last words).
#: 2. The VM was slow, measured apart from the product: the probe step, in a quiet guest before
#:    the rehearsal, timed a clock read (a system call under user-mode Linux) at
#:    SLOW_CLOCK_CALL_US or more, a SocketCAN send at SLOW_SEND_MS or more, or its 2e6-iteration
#:    Python loop at SLOW_LOOP_S or more (a VM held to part of a CPU: 0.308 s at 20 %, where the
#:    rehearsal collapsed; 0.132 s at 45 %, where it held; 0.04 to 0.12 s otherwise); or, during the
#:    rehearsal, the stall monitor (at the top real-time priority, every second) timed the median
#:    clock read at SLOW_MONITOR_CLOCK_US or more, or saw the guest stand still (the host not
#:    running it) for STALLED_S or more in all. The rehearsal held in every run seen with the
#:    probe at 37 to 63 us, 0.26 to 0.41 ms and 0.059 to 0.073 s, the monitor's median 66 us (idle and with two
#:    CPU-bound processes beside the VM: the guest's own load makes its system calls dearer); it
#:    collapsed on CI hosts whose probe measured 89 to 309 us and 0.52 to 0.92 ms (hypervisor
#:    steal of 20 to 44 %), where the stream fell to 62 to 187 Hz and replies were lost.
LOST_REAL_TIME_S = 1.0
SLOW_CLOCK_CALL_US = 80.0
SLOW_SEND_MS = 0.5
SLOW_LOOP_S = 0.2
SLOW_MONITOR_CLOCK_US = 150.0
STALLED_S = 1.0


#: Conformance checks that measure the unit over time (rates, periods, moves, the stream's
#: continuity and validity against the states the host saw): a starved VM fails them by what
#: it does to time (a batch of frames read late shares one arrival time, so a sample sent before
#: READY can be seen after it).
MEASURED = ("stream.", "rotation.", "link.", "timing.", "heartbeat.")
#: Words of another check's failure that say an answer was missing or late (what a starved VM
#: does), not wrong.
STARVED_SYMPTOMS = ("no reply", "within", "not run:", "after ", "late", "lasted", "only ")


def starved_symptom(name: str, message: str) -> bool:
    """Whether a failed check is what a starved VM causes: a measuring check, or another whose
    answer was missing or late; never an internal error."""
    text = message.lower()
    if "internal error" in text:
        return False
    return name.startswith(MEASURED) or any(w in text for w in STARVED_SYMPTOMS)


def sim_lag(log: Path) -> tuple[int, float] | None:
    """(slips, simulated seconds lost) from the simulator's log: its last words on stopping, or
    else its latest report of falling behind; None when the log says neither."""
    import re

    try:
        text = log.read_text(errors="replace")
    except OSError:
        return None
    stop = re.findall(r"fell behind its clock (\d+) time\(s\), ([0-9.]+) s of simulated", text)
    if stop:
        return int(stop[-1][0]), float(stop[-1][1])
    runs = re.findall(r"([0-9.]+) s of simulated time lost in (\d+) slip", text)
    if runs:
        return int(runs[-1][1]), float(runs[-1][0])
    return (0, 0.0) if "stopped at t=" in text else None


def probe_result() -> dict:
    """The probe step's figures from this run (``$HIL_OUT/steps/probe/result.json``), if any."""
    try:
        return json.loads((Path(os.environ["HIL_OUT"]) / "steps/probe/result.json").read_text())
    except (KeyError, OSError, ValueError):
        return {}


def judge(result: dict, hard: list[str], soft: list[str], sim_log: Path, mode: str) -> int:
    """0 passed, 1 failed, 3 not judged (the machine could not carry a real-time instrument: the
    soft failures are what a starved VM does, and the output says why it is not judged)."""
    if hard or not soft:
        result["verdict"] = "fail" if hard else "pass"
        return 1 if hard else 0
    if mode != "uml":
        # QEMU's guest is always slow (its timing checks are reported, not counted) and a host
        # with vcan0 of its own has no VM to starve: a failure there is a failure.
        result["verdict"] = "fail"
        return 1
    lost: list[str] = []
    lag = sim_lag(sim_log)
    if lag is not None:
        result["sim_slips"], result["sim_lost_s"] = lag[0], round(lag[1], 3)
        if lag[1] >= LOST_REAL_TIME_S:
            lost.append(f"the simulator fell behind its clock {lag[0]} times, {lag[1]:.1f} s lost")
    busy = result.get("machine_cpu_busy_percent")
    if lost and busy is not None:
        lost[-1] += f" (the guest's CPU {busy} % busy)"
    slow: list[str] = []
    probe = probe_result()
    if (probe.get("monotonic_call_us") or 0.0) >= SLOW_CLOCK_CALL_US:
        slow.append(f"the probe timed a clock read at {probe['monotonic_call_us']} us")
    if (probe.get("socketcan_send_ms") or 0.0) >= SLOW_SEND_MS:
        slow.append(f"the probe timed a SocketCAN send at {probe['socketcan_send_ms']} ms")
    if (probe.get("python_loop_2e6_s") or 0.0) >= SLOW_LOOP_S:
        slow.append(f"the probe timed its Python loop at {probe['python_loop_2e6_s']} s")
    stalls = result.get("machine_stalls")
    if isinstance(stalls, dict):
        clock = stalls.get("clock_call_us") or {}
        if (clock.get("p50") or 0.0) >= SLOW_MONITOR_CLOCK_US:
            slow.append(
                f"the stall monitor timed the median clock read at {clock['p50']} us "
                f"(p90 {clock.get('p90')} us, {len(clock.get('samples') or [])} samples)"
            )
        if stalls.get("stall_ms_total", 0.0) >= 1e3 * STALLED_S:
            slow.append(f"the guest stood still {stalls['stall_ms_total'] / 1e3:.1f} s in all")
    if lost and slow:
        result["verdict"] = "not judged"
        result["not_judged_because"] = (
            f"the {mode} VM could not carry a real-time instrument: "
            + "; ".join(lost) + "; and the VM was slow: " + "; ".join(slow)
        )  # fmt: skip
        print(f"rehearsal: NOT JUDGED: {result['not_judged_because']}", flush=True)
        return 3
    result["verdict"] = "fail"
    if lost or slow:
        result["why_judged"] = (
            "a failure is not excused by "
            + ("; ".join(lost) if lost else "; ".join(slow))
            + (" alone: the VM measured no slower than where the rehearsal holds" if lost
               else " alone: the instrument kept real time")
        )  # fmt: skip
    return 1


def spin_bound_deg(duration_s: float, arw_dpsh: float, latitude_deg: float) -> float:
    """White-noise bound of a spin over whole turns, level, both horizontal gyros, biases fitted:
    N / (Omega_H sqrt(T)), 1 sigma, deg (docs/spin.md, "How accurate"); written out here so that
    the rehearsal judges the product by the physics, not by the product's own figure."""
    n = math.radians(arw_dpsh) / 60.0  # rad/sqrt(s)
    omega_h = EARTH_RATE_RPS * math.cos(math.radians(latitude_deg))
    return math.degrees(n / (omega_h * math.sqrt(duration_s)))


def judge_spin(
    res: dict,
    truth_deg: float = TRUTH["azimuth"],
    latitude_deg: float = TRUTH["latitude"],
    arw_dpsh: float = SENSOR_ARW_DPSH,
) -> tuple[dict, list[str]]:
    """The figures of a spin ``find --json`` result and what is wrong with it (failures that no
    starved VM excuses: a heading off the truth by more than 5 sigma or 0.5 deg, a sigma below
    the white-noise bound, a result that is not a spin's).

    The bound is for the time the spin lasted (``spin.duration_s``); a spin of part turns, or
    samples lost on the way, only raise the sigma over it."""
    problems: list[str] = []
    spin = res.get("spin")
    if res.get("solver") != "spin" or not isinstance(spin, dict):
        return {}, [f"the spin find's result is not a spin's (solver {res.get('solver')!r})"]
    err = (res["azimuth_deg"] - truth_deg + 180.0) % 360.0 - 180.0
    sigma = float(res["sigma_deg"])
    bound = spin_bound_deg(float(spin["duration_s"]), arw_dpsh, latitude_deg)
    figures = {
        "azimuth_deg": res["azimuth_deg"],
        "azimuth_error_deg": err,
        "sigma_deg": sigma,
        "bound_deg": bound,
        "sigma_over_bound": round(sigma / bound, 3),
        "error_over_sigma": round(err / sigma, 2) if sigma > 0 else math.inf,
        "pitch_deg": res.get("pitch_deg"),
        "roll_deg": res.get("roll_deg"),
        "rate_dps": spin.get("rate_dps"),
        "duration_s": spin.get("duration_s"),
        "turns": round(float(spin.get("sweep_deg", math.nan)) / 360.0, 3),
        "samples": spin.get("samples"),
        "dropped": spin.get("dropped"),
        "consistent": res.get("consistent"),
    }
    if not abs(err) <= min(0.5, 5.0 * sigma):
        problems.append(
            f"spin: azimuth error {err:+.4f} deg exceeds 5 sigma ({sigma:.4f}) or 0.5 deg"
        )
    if not sigma >= SPIN_SIGMA_FLOOR * bound:
        problems.append(
            f"spin: sigma {sigma:.4f} deg beats the white-noise bound {bound:.4f} deg "
            f"({sigma / bound:.3f} of it)"
        )
    return figures, problems


def junit_cases(path: Path) -> dict[str, tuple[str, str]]:
    """Check name -> (``pass``/``fail``/``skip``, message) from the suite's JUnit XML."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return {}
    cases: dict[str, tuple[str, str]] = {}
    for tc in root.iter("testcase"):
        name = tc.get("name", "?")
        failure = tc.find("failure")
        if failure is None:
            failure = tc.find("error")
        if failure is not None:
            cases[name] = ("fail", failure.get("message", ""))
        elif tc.find("skipped") is not None:
            cases[name] = ("skip", tc.find("skipped").get("message", ""))
        else:
            out = tc.find("system-out")
            cases[name] = ("pass", (out.text or "").strip() if out is not None else "")
    return cases


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


T_START = time.monotonic()


def progress(text: str) -> None:
    """One line to the step's log as a phase starts or ends (read back when a step times out)."""
    print(f"rehearsal +{time.monotonic() - T_START:6.1f} s: {text}", flush=True)


def percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    s = sorted(values)
    return s[min(len(s) - 1, round(q / 100.0 * (len(s) - 1)))]


def cpu_seconds_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def machine_cpu() -> tuple[float, float] | None:
    """(busy, total) jiffies of all CPUs from /proc/stat (the guest's own CPU in a VM)."""
    try:
        with open("/proc/stat") as f:
            fields = [float(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)  # idle + iowait
    return sum(fields) - idle, sum(fields)


def drain(proc: subprocess.Popen, log: Path, quiet_s: float = 2.0, timeout: float = 120.0) -> float:
    """Wait until candump has written what the bus carried (its log stops growing); seconds.

    candump may run behind (niced, with a large receive buffer): stopping it at once would drop
    what is still queued in its socket. Once the bus is quiet it is given back normal priority.
    """
    try:
        os.setpriority(os.PRIO_PROCESS, proc.pid, 0)
    except OSError:
        pass
    t0 = since = time.monotonic()
    last = -1
    while time.monotonic() - t0 < timeout and proc.poll() is None:
        try:
            size = log.stat().st_size
        except OSError:
            size = -1
        if size != last:
            last, since = size, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            break
        time.sleep(0.25)
    return time.monotonic() - t0


def wait_for_heartbeat(candump: str, channel: str, status_id: int, timeout: float) -> float | None:
    """Seconds until a STATUS frame is on the bus (a second candump, filtered to that one id,
    ending at the first frame); None: none within ``timeout``."""
    t0 = time.monotonic()
    try:
        subprocess.run(
            [candump, "-n", "1", f"{channel},{status_id:03X}:7FF"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=timeout, check=True,
        )  # fmt: skip
    except (subprocess.TimeoutExpired, subprocess.CalledProcessError):
        return None
    return time.monotonic() - t0


def candump_log(folder: Path, proc: subprocess.Popen | None, timeout: float = 60.0) -> Path | None:
    """The log ``candump -l`` opened in ``folder`` (it names it by the date), once it exists."""
    t0 = time.monotonic()
    while proc is not None and time.monotonic() - t0 < timeout:
        logs = sorted(folder.glob("candump-*.log"))
        if logs:
            return logs[-1]
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    return None


def analyse_candump(path: Path, dbc: Path, find_end: float, bad_input_from: float) -> dict:
    """Decode every frame with cantools; tick continuity and cycle times of the stream.

    Arrival jitter is |interval - 5 ms| between consecutive SAMPLE_AUX frames (one per tick) by
    the guest kernel's receive timestamps, while ``find`` ran (until ``find_end``, epoch seconds):
    the unit at its default 200 Hz with a host reading it. From ``bad_input_from`` on, the
    conformance suite puts malformed and foreign frames on the bus on purpose: from then on only
    the device's own frames must all decode.
    """
    import cantools

    db = cantools.database.load_file(str(dbc))
    known = {m.frame_id for m in db.messages}
    command_id = db.get_message_by_name("COMMAND").frame_id
    reply_id = db.get_message_by_name("REPLY").frame_id
    aux_id = db.get_message_by_name("SAMPLE_AUX").frame_id
    status_id = db.get_message_by_name("STATUS").frame_id
    # The defined opcodes are the reply multiplexer's choices.
    opcodes = set(db.get_message_by_name("REPLY").get_signal_by_name("Opcode").choices)
    frames = unknown = undecodable = deliberate = undefined_echo = 0
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
        from_host = arb not in known or arb == command_id
        if t >= bad_input_from and from_host:
            deliberate += 1
            continue
        if arb not in known:
            unknown += 1
            continue
        if arb == reply_id and len(payload) >= 2 and payload[1] not in opcodes:
            # A reply echoing an undefined opcode (the answer to the conformance suite's bad
            # input): the DBC multiplexes replies on the opcode, so cantools cannot name it.
            undefined_echo += 1
            continue
        try:
            decoded = db.decode_message(arb, payload, decode_choices=False, allow_truncated=True)
        except Exception:
            undecodable += 1
            continue
        if arb == aux_id:
            aux_times.append(t)
            aux_ticks.append(int(decoded["Tick"]))
        elif arb == status_id:
            status_times.append(t)
    # Streams run in bursts (one per window); a pause longer than 0.5 s starts a new burst, in
    # which the tick must advance by one each time.
    lost, periods, find_periods = 0, [], []
    for i in range(1, len(aux_ticks)):
        dt = aux_times[i] - aux_times[i - 1]
        if dt > 0.5:
            continue
        gap = (aux_ticks[i] - aux_ticks[i - 1]) & 0xFF
        lost += gap - 1 if gap else 255
        periods.append(dt)
        if aux_times[i] <= find_end:
            find_periods.append(dt)
    jitter = [abs(p - 0.005) for p in find_periods]
    # Statuses while find ran: heartbeats, and the answers to its GET_STATUS polls.
    hb = [b - a for a, b in itertools.pairwise(status_times) if b <= find_end and b - a < 1.0]
    ms = lambda v: round(1e3 * v, 3)  # noqa: E731
    return {
        "frames": frames,
        "unknown_frames": unknown,
        "undecodable_frames": undecodable,
        "conformance_bad_input_frames": deliberate,
        "replies_to_undefined_opcodes": undefined_echo,
        "sample_ticks": len(aux_ticks),
        "ticks_lost": lost,
        "sample_arrival_jitter_ms": {
            "p50": ms(percentile(jitter, 50)),
            "p99": ms(percentile(jitter, 99)),
            "max": ms(max(jitter, default=math.nan)),
            "over_2ms_percent": round(100 * sum(j > 0.002 for j in jitter) / len(jitter), 2)
            if jitter
            else None,
            "intervals": len(jitter),
            "while": "find (200 Hz)",
        },
        "sample_period_ms_mean": ms(sum(find_periods) / len(find_periods))
        if find_periods
        else math.nan,
        "heartbeats": len(status_times),
        "heartbeat_period_ms_p50": ms(percentile(hb, 50)),
    }


class Rehearsal:
    """What the steps share: the options, the command, the bus, and what they find.

    ``hard``: failures that no starved machine excuses (see judge()): a wrong heading, frames
    the DBC does not know, a missing report, a hang, an internal error, a wrong answer, a dead
    simulator; ``failures``: the others; ``reported``: report-only items that did not hold, with
    what was measured; ``cpu``: CPU seconds per step.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.out: Path = args.out
        self.nf = str(Path(sys.executable).parent / "northfinder")
        self.ch: str = args.channel
        self.report_only: dict[str, str] = REPORT_ONLY[args.mode]
        self.result: dict = {"channel": args.channel, "mode": args.mode}
        self.hard: list[str] = []
        self.failures: list[str] = []
        self.reported: dict[str, str] = {}
        self.cpu: dict[str, float] = {}


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--repo", type=Path, required=True)
    # The suite's observation window (heartbeat period and jitter, stream rate). 10 s hold 100
    # statuses and 2000 samples; the find before it streams 40 s more on vcan0, judged by candump.
    # Against a real unit the suite's own default (30 s) stays.
    ap.add_argument("--stream-seconds", type=float, default=10.0)
    ap.add_argument(
        "--find-timeout", type=float, default=240.0, help="s (a 0,180 find takes ~45 s)"
    )
    ap.add_argument("--conformance-timeout", type=float, default=360.0, help="s (~140 s in a VM)")
    ap.add_argument(
        "--accept-timeout",
        type=float,
        default=600.0,
        help=f"s (a {ACCEPT_STATIC_S:g} s still record and {ACCEPT_RUNS} runs of 0,180: ~3 min)",
    )
    ap.add_argument(
        "--mode", choices=sorted(REPORT_ONLY), default=os.environ.get("HIL_MODE", "direct")
    )
    return ap.parse_args()


def start_candump(r: Rehearsal) -> tuple[subprocess.Popen | None, Path, Path]:
    """candump on the bus: the process (None without can-utils), its folder and its log."""
    candump = shutil.which("candump")
    # candump -l writes its log (candump-<date>.log in its working directory) through a stdio
    # buffer; -L would flush stdout after every frame: one system call a frame more, which a VM
    # makes dear (about a third of candump's CPU under user-mode Linux).
    dump_dir = Path(tempfile.mkdtemp(prefix="candump-", dir=r.out))
    dump_cmd = [candump, "-l", "-r", "8388608", r.ch]
    if r.args.mode == "uml":
        # One guest CPU: candump gives way to the instrument and the host. It loses nothing by
        # waiting, as its timestamps are the kernel's; a 32 MiB receive buffer holds about 40 s
        # of the bus's traffic meanwhile. It writes to the guest's own memory (HIL_GUEST_TMP, a
        # tmpfs): a write to the host's filesystem holds the whole guest kernel until the host
        # is done. The log is moved out when the bus is quiet.
        dump_cmd = ["nice", "-n", "19", candump, "-l", "-r", str(32 << 20), r.ch]
        if os.environ.get("HIL_GUEST_TMP"):
            dump_dir.rmdir()
            dump_dir = Path(tempfile.mkdtemp(prefix="candump-", dir=os.environ["HIL_GUEST_TMP"]))
    dump = start(dump_cmd, dump_dir / "candump.out", cwd=dump_dir) if candump else None
    dump_log = candump_log(dump_dir, dump)
    if dump is not None and dump_log is None:
        r.hard.append(f"candump did not start: {(dump_dir / 'candump.out').read_text()[-300:]}")
        dump_log = dump_dir / "candump.log"
        dump_log.touch()
    assert dump_log is not None or dump is None
    return dump, dump_dir, dump_log if dump_log is not None else dump_dir / "candump.log"


def sim_command(r: Rehearsal) -> list[str]:
    sim_cmd = [r.nf, "sim", "-i", "socketcan", "-c", r.ch, "--warmup", "0", "--sensor", SENSOR, "--seed", "7",
               "--azimuth", str(TRUTH["azimuth"]), "--latitude", str(TRUTH["latitude"]),
               "--pitch", str(TRUTH["pitch"]), "--roll", str(TRUTH["roll"])]  # fmt: skip
    if r.args.mode != "direct":
        # One guest CPU carries the instrument, the host and candump; a real unit has a processor
        # of its own. The simulator is given precedence so that the unit keeps its pace and a
        # busy guest shows as a slow host (which reads late from its socket buffer), not as an
        # instrument that falls behind.
        sim_cmd = ["nice", "-n", "-10", *sim_cmd]
    return sim_cmd


def run_find(r: Rehearsal, label: str, stem: str, wall_key: str, options: list[str]) -> str | None:
    """Run ``find`` on the bus with these options, its time and CPU in ``cpu[stem]`` and
    ``result[wall_key]``, its output in <stem>.json and <stem>.err; its JSON when it
    exited 0, else None with the failure counted."""
    t0 = time.monotonic()
    c0 = cpu_seconds_children()
    run = subprocess.run(
        [r.nf, "find", "-i", "socketcan", "-c", r.ch, "--json", "--latitude", str(TRUTH["latitude"]),
         "--link-timeout", "3", "--reply-timeout", "2", "--timeout", "300", *options],
        capture_output=True, text=True, timeout=r.args.find_timeout,
    )  # fmt: skip
    progress(f"{label} exited {run.returncode} after {time.monotonic() - t0:.1f} s")
    r.cpu[stem.replace("-", "_")] = cpu_seconds_children() - c0
    r.result[wall_key] = round(time.monotonic() - t0, 1)
    (r.out / f"{stem}.json").write_text(run.stdout)
    (r.out / f"{stem}.err").write_text(run.stderr)
    if run.returncode == 0:
        return run.stdout
    # Exit 1 is a link or device error (a lost reply, a stalled stream), or an internal
    # error (a bug, said so on stderr); any other code is a bad argument: only a link or
    # device error is what a starved VM causes.
    internal = "internal error" in run.stderr or "Traceback" in run.stderr
    (r.failures if run.returncode == 1 and not internal else r.hard).append(
        f"{label} exited {run.returncode}: {run.stderr.strip()[-300:]}"
    )
    return None


def find_steps(r: Rehearsal) -> None:
    """The find of the plan 0,180 against the truth, and the spin find."""
    result, hard = r.result, r.hard
    # the plan of the timings measured so far (find's default is now 0,180,180,0)
    found = run_find(
        r, "find", "find", "find_wall_s",
        ["--positions", "0,180", "--record", str(r.out / "windows.npz")],
    )  # fmt: skip
    if found is not None:
        res = json.loads(found)
        err = (res["azimuth_deg"] - TRUTH["azimuth"] + 180.0) % 360.0 - 180.0
        result.update(
            azimuth_deg=res["azimuth_deg"], truth_deg=TRUTH["azimuth"], azimuth_error_deg=err,
            sigma_deg=res["sigma_deg"], pitch_deg=res["pitch_deg"], roll_deg=res["roll_deg"],
        )  # fmt: skip
        if not abs(err) <= min(0.5, 5.0 * res["sigma_deg"]):
            hard.append(f"azimuth error {err:+.4f} deg exceeds 5 sigma ({res['sigma_deg']:.4f})")


def spin_step(r: Rehearsal) -> None:
    """The spin find (protocol 1.1): the table turns at a constant rate for one whole turn, and
    the heading is the phase of the Earth rate on the horizontal gyros."""
    progress(f"running find --spin {SPIN_RATE_DPS:g}")
    spun = run_find(
        r, "find --spin", "find-spin", "spin_find_wall_s", ["--spin", f"{SPIN_RATE_DPS:g}"]
    )
    if spun is not None:
        figures, problems = judge_spin(json.loads(spun))
        r.result["spin"] = figures
        r.hard.extend(problems)


def conformance_step(r: Rehearsal) -> None:
    """The conformance suite on the bus, its checks counted but for the mode's report-only ones."""
    result, out, hard = r.result, r.out, r.hard
    margins = CONFORMANCE_MARGINS.get(r.args.mode, [])
    result["conformance_timing"] = " ".join(margins) if margins else "protocol defaults"
    progress("running the conformance suite")
    t0 = time.monotonic()
    c0 = cpu_seconds_children()
    conf = subprocess.run(
        [r.nf, "conformance", "-i", "socketcan", "-c", r.ch, "--stream-seconds", str(r.args.stream_seconds),
         "--junit", str(out / "conformance.xml"), *margins],
        capture_output=True, text=True, timeout=r.args.conformance_timeout,
    )  # fmt: skip
    progress(f"conformance exited {conf.returncode} after {time.monotonic() - t0:.1f} s")
    r.cpu["conformance"] = cpu_seconds_children() - c0
    result["conformance_wall_s"] = round(time.monotonic() - t0, 1)
    (out / "conformance.txt").write_text(conf.stdout + conf.stderr)
    result["conformance_exit"] = conf.returncode
    last = [line for line in conf.stdout.splitlines() if "passed" in line]
    result["conformance"] = last[-1].strip() if last else conf.stderr.strip()[-300:]
    cases = junit_cases(out / "conformance.xml")
    counted = {n: c for n, c in cases.items() if n not in r.report_only and c[0] != "skip"}
    failed = sorted(n for n, (status, _) in counted.items() if status == "fail")
    result["conformance_counted"] = {
        "checks": len(counted),
        "passed": len(counted) - len(failed),
        "failed": failed,
        "skipped": sorted(n for n, c in cases.items() if c[0] == "skip"),
    }
    # The conformance checks of the spin command (protocol 1.1), by name in the summary.
    result["spin_conformance"] = {
        n: status for n, (status, _) in cases.items() if n.startswith("spin.")
    }
    for name, (status, message) in cases.items():
        if name in r.report_only:
            r.reported[name] = f"{status.upper()}: {message}" if status == "fail" else status
    if not cases:
        hard.append(f"conformance: no JUnit report ({result['conformance']})")
    elif conf.returncode not in (0, 1, 3):  # 3: a check not judged (a skip in the JUnit)
        hard.append(f"conformance exited {conf.returncode}: {result['conformance']}")
    elif failed:
        # A check that failed on a missing or late answer is what a starved VM causes; one
        # that got a wrong answer (or hit an internal error) is the product's.
        wrong = [n for n in failed if not starved_symptom(n, counted[n][1])]
        if wrong:
            hard.append(
                "conformance (wrong answers, not missing ones): "
                + "; ".join(f"{n}: {counted[n][1][:160]}" for n in wrong)
            )
        if len(wrong) < len(failed):
            r.failures.append(f"conformance: {[n for n in failed if n not in wrong]}")


#: The acceptance step's datasheet: the simulator's sensor at three times its ARW, the plan 0,180
#: at a repeatability a few runs can bound, READY within a minute of a RESET (the simulator runs
#: without warm-up), protocol 1.1 and the one conformance check that is not already run above.
ACCEPT_DATASHEET = f"""name = "rehearsal: {SENSOR}"
[gyro]
arw_dpsh = {3 * SENSOR_ARW_DPSH!r}
[north_finding]
sigma_deg = 1.0
positions_deg = [0.0, 180.0]
latitude_deg = {TRUTH["latitude"]!r}
[unit]
time_to_ready_s = 60.0
protocol_version = "1.1"
conformance = ["identify"]
"""
ACCEPT_STATIC_S = 60.0
ACCEPT_RUNS = 4
#: accept's exit statuses: 0 every line passed, 4 no line failed but one is not resolved (two
#: runs and a minute still decide little); 1 a line failed or the link did.
ACCEPT_OK = (0, 4)


def accept_step(r: Rehearsal) -> None:
    """One acceptance of the unit on the bus (``northfinder accept``): every stage over
    SocketCAN, its lines in result.json; a line that FAILs counts as a failure."""
    datasheet = r.out / "accept-datasheet.toml"
    datasheet.write_text(ACCEPT_DATASHEET)
    progress("running accept")
    t0 = time.monotonic()
    c0 = cpu_seconds_children()
    run = subprocess.run(
        [r.nf, "accept", "--datasheet", str(datasheet), "-i", "socketcan", "-c", r.ch,
         "--latitude", str(TRUTH["latitude"]), "--link-timeout", "3", "--reply-timeout", "2",
         "--static-s", f"{ACCEPT_STATIC_S:g}", "--runs", str(ACCEPT_RUNS), "--orientations", "2",
         "-o", str(r.out / "accept"), "--json"],
        capture_output=True, text=True, timeout=r.args.accept_timeout,
    )  # fmt: skip
    progress(f"accept exited {run.returncode} after {time.monotonic() - t0:.1f} s")
    r.cpu["accept"] = cpu_seconds_children() - c0
    r.result["accept_wall_s"] = round(time.monotonic() - t0, 1)
    (r.out / "accept.err").write_text(run.stderr)
    r.result["accept_exit"] = run.returncode
    try:
        doc = json.loads(run.stdout)
    except json.JSONDecodeError:
        doc = None
    if doc is not None:
        r.result["accept"] = {
            "verdict": doc["verdict"],
            "lines": {line["key"]: line["verdict"] for line in doc["lines"]},
        }
    if run.returncode in ACCEPT_OK and doc is not None:
        return
    internal = "internal error" in run.stderr or "Traceback" in run.stderr
    failed = [k for k, v in (r.result.get("accept") or {}).get("lines", {}).items() if v == "FAIL"]
    (r.failures if run.returncode == 1 and not internal else r.hard).append(
        f"accept exited {run.returncode}: "
        + (f"lines failed: {failed}" if failed else run.stderr.strip()[-300:])
    )


def stop_instruments(r: Rehearsal, sim: subprocess.Popen, dump: subprocess.Popen | None,
                     dump_dir: Path, dump_log: Path) -> float:  # fmt: skip
    """Stop the simulator and drain candump (its log to ``out``); when the simulator stopped."""
    progress("stopping the simulator, draining candump")
    result = r.result
    c0 = cpu_seconds_children()
    sim_died = sim.poll()
    result["sim_exit"] = stop(sim)
    sim_stopped = time.time()
    if sim_died is not None or result["sim_exit"] not in (0, None):
        r.hard.append(
            f"the simulator {'died' if sim_died is not None else 'exited'} with status "
            f"{result['sim_exit']} (its log: sim.log)"
        )
    r.cpu["sim"] = cpu_seconds_children() - c0
    if dump is not None:
        c0 = cpu_seconds_children()
        result["candump_drain_s"] = round(drain(dump, dump_log), 1)
        stop(dump)
        r.cpu["candump"] = cpu_seconds_children() - c0
        shutil.move(dump_log, r.out / "candump.log")
        if (dump_dir / "candump.out").stat().st_size:
            shutil.move(dump_dir / "candump.out", r.out / "candump.stderr")
    shutil.rmtree(dump_dir, ignore_errors=True)
    return sim_stopped


def machine_figures(r: Rehearsal, monitor: subprocess.Popen, t_step: float, cpu0: float,
                    machine0: tuple[float, float] | None) -> None:  # fmt: skip
    """The stall monitor's figures, the CPU of each step and of the guest."""
    result = r.result
    monitor.send_signal(signal.SIGTERM)
    try:
        mon_out, _ = monitor.communicate(timeout=20)
        stalls = json.loads(mon_out.strip().splitlines()[-1])
        stalls["stalls_ms"] = stalls["stalls_ms"][:100]
        result["machine_stalls"] = stalls
    except (subprocess.TimeoutExpired, json.JSONDecodeError, IndexError) as exc:
        monitor.kill()
        result["machine_stalls"] = f"stall monitor failed: {exc!r}"
    wall = time.monotonic() - t_step
    machine1 = machine_cpu()
    result["cpu_seconds"] = {k: round(v, 1) for k, v in r.cpu.items()}
    result["cpu_seconds"]["all_children"] = round(cpu_seconds_children() - cpu0, 1)
    result["step_wall_s"] = round(wall, 1)
    if machine0 and machine1 and machine1[1] > machine0[1]:
        # How close the instrument, the host and candump together come to the guest's CPU.
        result["machine_cpu_busy_percent"] = round(
            100 * (machine1[0] - machine0[0]) / (machine1[1] - machine0[1]), 1
        )


def bus_figures(
    r: Rehearsal, find_end: float, conformance_start: float, sim_stopped: float
) -> None:
    """The candump log against protocol.dbc: frames, lost ticks and the unit's cycle times."""
    out, result = r.out, r.result
    stats = analyse_candump(
        out / "candump.log", r.args.repo / "protocol.dbc", find_end, conformance_start
    )
    result.update(stats)
    # The log must reach the end of the traffic: the simulator's heartbeats run until it stops.
    lines = (out / "candump.log").read_text(errors="replace").split("\n(")
    last = float(lines[-1].split(")")[0].lstrip("(")) if len(lines) > 1 else math.nan
    result["candump_log_ends_before_sim_stop_s"] = round(sim_stopped - last, 2)
    if not sim_stopped - last <= 2.0:
        r.failures.append(
            f"candump's log ends {sim_stopped - last:.1f} s before the simulator stopped: "
            "traffic not recorded"
        )
    if stats["unknown_frames"] or stats["undecodable_frames"]:
        r.hard.append(
            f"{stats['unknown_frames']} unknown and {stats['undecodable_frames']} undecodable frames"
        )
    if stats["ticks_lost"]:
        r.failures.append(f"{stats['ticks_lost']} sample ticks lost on the bus")
    # The cycle times on the bus are the unit's timing.
    pace = {
        "pace.sample_period": (
            abs(stats["sample_period_ms_mean"] - 5.0) <= 0.05,
            f"mean sample period {stats['sample_period_ms_mean']:.3f} ms, not 5 ms +- 1 %",
        ),
        "pace.heartbeat_period": (
            abs(stats["heartbeat_period_ms_p50"] - 100.0) <= 10.0,
            f"median heartbeat period {stats['heartbeat_period_ms_p50']:.1f} ms, not 100 ms +- 10 %",
        ),
    }
    for name, (ok, message) in pace.items():
        if name in r.report_only:
            r.reported[name] = "pass" if ok else f"FAIL: {message}"
        elif not ok:
            r.failures.append(message)


#: The steps on the bus, in order; the conformance suite's start marks where its deliberate bad
#: input begins on the bus (everything after it is counted apart: accept runs after it).
STEPS = ("find", "spin", "conformance", "accept")


def main() -> int:
    args = parse_args()
    r = Rehearsal(args)
    dump, dump_dir, dump_log = start_candump(r)
    sim_cmd = sim_command(r)
    import cantools

    dbc = cantools.database.load_file(str(args.repo / "protocol.dbc"))
    status_id = dbc.get_message_by_name("STATUS").frame_id
    # A VM is a machine of its own: a stall monitor at the top real-time priority inside it
    # tells the guest's own stalls (the host not running it) apart from contention inside it.
    mon_cmd = [sys.executable, str(Path(__file__).with_name("stallmon.py")), "--period", "0.02"]
    if args.mode != "direct" and shutil.which("chrt"):
        mon_cmd = ["chrt", "-f", "99", *mon_cmd]
    monitor = subprocess.Popen(mon_cmd, stdout=subprocess.PIPE, text=True, start_new_session=True)
    cpu0, machine0 = cpu_seconds_children(), machine_cpu()
    t_step = time.monotonic()
    progress(f"starting the simulator: {' '.join(sim_cmd[1:])}")
    sim = start(sim_cmd, r.out / "sim.log")
    find_end = conformance_start = math.inf
    try:
        candump = shutil.which("candump")
        waited = wait_for_heartbeat(candump, r.ch, status_id, 120.0) if dump else None
        if dump is not None and waited is None:
            r.hard.append("no heartbeat from the simulator on the bus within 120 s")
        r.result["sim_first_heartbeat_s"] = None if waited is None else round(waited, 2)
        progress(f"first heartbeat after {waited} s; running find")
        find_steps(r)
        find_end = time.time()
        spin_step(r)
        conformance_start = time.time()
        conformance_step(r)
        accept_step(r)
    except subprocess.TimeoutExpired as exc:
        r.hard.append(f"{Path(exc.cmd[0]).name} {exc.cmd[1]} did not end within {exc.timeout:g} s")
        progress(r.hard[-1])
    finally:
        sim_stopped = stop_instruments(r, sim, dump, dump_dir, dump_log)
    machine_figures(r, monitor, t_step, cpu0, machine0)
    if dump is None:
        r.hard.append("candump (can-utils) not found: traffic not recorded")
    else:
        bus_figures(r, find_end, conformance_start, sim_stopped)
    r.result["report_only"] = {
        name: {"result": r.reported.get(name, "not run"), "why_not_counted": why}
        for name, why in r.report_only.items()
    }
    r.result["failures"] = r.hard + r.failures
    rc = judge(r.result, r.hard, r.failures, r.out / "sim.log", args.mode)
    (r.out / "result.json").write_text(json.dumps(r.result, indent=2))
    print(json.dumps(r.result, indent=2))
    return rc


if __name__ == "__main__":
    sys.exit(main())
