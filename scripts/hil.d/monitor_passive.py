"""Step "monitor": ``northfinder monitor --passive`` on the bus beside another host's find.

1. ``northfinder sim -i socketcan -c IF`` runs as its own process (real time);
2. ``northfinder monitor --passive`` runs in a tmux session of 120 x 40 (a terminal, as a person
   runs it), listening only;
3. ``northfinder find`` runs as a third process and drives the unit;
4. once the find is done the monitor's screen is captured (``tmux capture-pane -p``), the
   monitor quits (``q``) and writes its counters (``--summary``).

Judged: the monitor saw the find's session (commands, every one answered), the stream without
a lost tick, the unit's state, and the find's result agrees with the truth; the monitor sent
nothing (every command on the bus is the find's: as many commands as the find's replies).
Writes ``result.json``, ``screen.txt``, ``monitor.json``; exit 0 passed, 1 failed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

TRUTH_DEG = 42.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--channel", default="vcan0")
    args = ap.parse_args()
    out: Path = args.out
    nf = str(Path(sys.executable).parent / "northfinder")
    ch = args.channel
    tmux = shutil.which("tmux")
    result: dict = {"channel": ch}
    failures: list[str] = []
    if tmux is None:
        result["skipped"] = "tmux is not installed"
        (out / "result.json").write_text(json.dumps(result, indent=2))
        print("monitor: skipped, no tmux")
        return 0
    sim = subprocess.Popen(
        ["nice", "-n", "-10", nf, "sim", "-i", "socketcan", "-c", ch, "--warmup", "0",
         "--sensor", "nav-fog", "--seed", "7", "--azimuth", str(TRUTH_DEG)],
        stdout=(out / "sim.log").open("w"), stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    summary = out / "monitor.json"
    session = "nfmon"
    mon = (
        f"{nf} monitor -i socketcan -c {ch} --passive --refresh 2 --plot-rate 0.5 "
        f"--summary {summary}"
    )
    sock = ["-L", "northfinder-hil"]
    try:
        time.sleep(3.0)
        subprocess.run(
            [tmux, *sock, "new-session", "-d", "-s", session, "-x", "120", "-y", "40", mon],
            check=True,
        )  # fmt: skip
        time.sleep(5.0)
        t0 = time.monotonic()
        find = subprocess.run(
            [nf, "find", "-i", "socketcan", "-c", ch, "--json", "--latitude", "34",
             "--positions", "0,180", "--window", "5", "--link-timeout", "3",
             "--reply-timeout", "2", "--timeout", "300"],
            capture_output=True, text=True, timeout=400,
        )  # fmt: skip
        result["find_wall_s"] = round(time.monotonic() - t0, 1)
        result["find_exit"] = find.returncode
        (out / "find.json").write_text(find.stdout)
        (out / "find.err").write_text(find.stderr)
        time.sleep(3.0)  # the monitor's next redraws
        screen = subprocess.run(
            [tmux, *sock, "capture-pane", "-p", "-t", session], capture_output=True, text=True
        ).stdout
        (out / "screen.txt").write_text(screen)
        subprocess.run([tmux, *sock, "send-keys", "-t", session, "q"])
        for _ in range(60):
            if summary.exists():
                break
            time.sleep(0.5)
        if find.returncode == 0:
            res = json.loads(find.stdout)
            err = (res["azimuth_deg"] - TRUTH_DEG + 180.0) % 360.0 - 180.0
            result.update(azimuth_deg=res["azimuth_deg"], sigma_deg=res["sigma_deg"], error=err)
        else:
            failures.append(f"find exited {find.returncode}: {find.stderr.strip()[-200:]}")
        if not summary.exists():
            failures.append("the monitor wrote no summary (it did not quit on q)")
        else:
            m = json.loads(summary.read_text())
            result["monitor"] = m
            if m["commands"] == 0 or m["replies"] != m["commands"]:
                failures.append(f"commands {m['commands']}, replies {m['replies']}")
            if m["ticks_lost"]:
                failures.append(f"the monitor counted {m['ticks_lost']} ticks lost")
            if m["samples"] < 1000:
                failures.append(f"the monitor saw {m['samples']} samples of the find's windows")
        if "PASSIVE" not in screen or "ROTATE_TO 180.000 deg -> OK" not in screen.replace(
            "\n", " "
        ):
            failures.append("the screen does not show the passive session's rotation")
    finally:
        subprocess.run([tmux, *sock, "kill-server"], capture_output=True)
        sim.terminate()
        try:
            sim.wait(20)
        except subprocess.TimeoutExpired:
            sim.kill()
    result["failures"] = failures
    (out / "result.json").write_text(json.dumps(result, indent=2))
    print(f"monitor: {'passed' if not failures else 'FAILED: ' + '; '.join(failures)}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
