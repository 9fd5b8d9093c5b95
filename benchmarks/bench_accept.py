"""``northfinder accept`` of a good simulated unit, many seeds: how often a line FAILs it.

Run: ``.venv/bin/python benchmarks/bench_accept.py [--seeds 200] [--out FILE.jsonl]``

The unit is ``tests/data/accept-unit.toml`` (a tactical gyro whose noise terms ten minutes of still
record resolve); the datasheet is twice its figures (the tests' good datasheet): the Allan lines,
the bias repeatability between windows on each axis, and the repeatability of the headings of
the plan ``0,180,180,0`` (10 s windows), 2.1 deg at 34 deg, about three times the planner's
0.65 deg. Only the statistical stages run (the conformance suite and the protocol lines decide
PASS or FAIL without an interval): ``--static-s 300``, ``--runs 8 --orientations 2``,
``--warmup 5``, in virtual time, each seed a command of its own in this process.

Each line FAILs only when the lower end of its 90 % interval is above the limit, so for a unit
exactly at a limit the line FAILs at most 5 % of the time (its design value); for this unit,
whose figures are half the limits, the design value of a chi-squared line is
``P(chi2_n > 4 chi2_0.95,n)`` (the limit twice the true 1 sigma): printed beside the measured rate.
A seed's result goes to ``--out`` (one JSON line) as it ends, so a stopped run keeps its seeds.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

from scipy.stats import chi2

from northfinder.cli import main as cli

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "tests" / "data" / "accept-unit.toml"
DATASHEET = """name = "accept-unit x 2"
[gyro]
arw_dpsh = 0.02
bias_instability_dph = 0.5
bias_repeatability_dph = 1.0
[accel]
vrw_ug_rthz = 20.0
bias_instability_ug = 40.0
[north_finding]
sigma_deg = 2.1
positions_deg = [0.0, 180.0, 180.0, 0.0]
"""
STAGES = ["--static-s", "300", "--runs", "8", "--orientations", "2", "--warmup", "5"]


def one(seed: int, tmp: Path) -> dict[str, object]:
    ds = tmp / "datasheet.toml"
    ds.write_text(DATASHEET)
    argv = ["accept", "--datasheet", str(ds), "--sim", "--sensor", str(UNIT), "--seed", str(seed)]
    argv += ["-o", str(tmp / f"acc-{seed}"), *STAGES, "--json"]
    out, err = io.StringIO(), io.StringIO()
    t0 = time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    cpu = time.process_time() - t0
    result = json.loads(out.getvalue())
    return {
        "seed": seed,
        "code": code,
        "cpu_s": cpu,
        "verdict": result["verdict"],
        "lines": {x["key"]: x["verdict"] for x in result["lines"]},
    }


def design_value(dof: int, ratio: float = 2.0) -> float:
    """P(FAIL) of a chi-squared line whose limit is ``ratio`` times the true 1 sigma."""
    return float(chi2.sf(ratio * ratio * chi2.ppf(0.95, dof), dof))


def summary(rows: list[dict[str, object]]) -> str:
    n = len(rows)
    keys = sorted({k for r in rows for k in r["lines"]})  # type: ignore[attr-defined]
    out = [f"{n} seeds; CPU {sum(r['cpu_s'] for r in rows) / n:.1f} s a seed"]  # type: ignore[misc]
    bad = sum(r["verdict"] == "FAIL" for r in rows)
    low, high = _interval(bad, n)
    out.append(
        f"any line FAIL: {bad}/{n} = {bad / n:.2%} (95 % interval {low:.2%} to {high:.2%}, "
        f"Clopper-Pearson; one-sided 95 % upper bound {_upper(bad, n):.2%})"
    )
    for k in keys:
        counts: dict[str, int] = {}
        for r in rows:
            v = r["lines"][k]  # type: ignore[index]
            counts[v] = counts.get(v, 0) + 1
        out.append(f"  {k:<32} " + ", ".join(f"{v} {c}" for v, c in sorted(counts.items())))
    out.append(
        "design (limit = 2 x true sigma): repeatability of headings (7 dof) "
        f"{design_value(7):.1e}, bias repeatability per axis (16 dof) {design_value(16):.1e}; "
        "any line exactly at its limit: 5 %"
    )
    heading, change = predicted_sigmas()
    out.append(
        f"the planner's 1 sigma for this unit: headings {heading:.3g} deg (limit {2.1 / heading:.2f} "
        f"x: design {design_value(7, 2.1 / heading):.1e}), change between windows at one angle "
        f"{change:.3g} deg/h (limit {1.0 / change:.2f} x: design "
        f"{design_value(16, 1.0 / change):.1e})"
    )
    return "\n".join(out)


def predicted_sigmas() -> tuple[float, float]:
    """The planner's 1 sigma of the headings and of a window mean's change between the windows at
    one angle, for the unit and the plan of :data:`DATASHEET` at 34 deg, a 5 s warm-up."""
    from northfinder.cli.simulated import load_sensor
    from northfinder.host.acceptance import same_angle_pairs
    from northfinder.host.accuracy import predict, window_change_dph
    from northfinder.host.plan import Plan
    from northfinder.simwindows import error_model

    model = error_model(load_sensor(str(UNIT)))
    plan = Plan((0.0, 180.0, 180.0, 0.0), 10.0, 0.0, "none", "auto")
    heading = predict(model, plan, 34.0, warmup_s=5.0).sigma_deg
    pairs = same_angle_pairs(plan.positions_deg)
    return heading, window_change_dph(model, plan, pairs, warmup_s=5.0)


def _interval(k: int, n: int) -> tuple[float, float]:
    """Two-sided 95 % interval of a rate seen k times in n (Clopper-Pearson)."""
    from scipy.stats import beta

    low = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    high = 1.0 if k >= n else float(beta.ppf(0.975, k + 1, n - k))
    return low, high


def _upper(k: int, n: int) -> float:
    """One-sided 95 % upper bound of a rate seen k times in n (Clopper-Pearson)."""
    from scipy.stats import beta

    return 1.0 if k >= n else float(beta.ppf(0.95, k + 1, n - k))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=200)
    p.add_argument("--first", type=int, default=1)
    p.add_argument("--out", default="bench_accept.jsonl")
    args = p.parse_args()
    rows = []
    done = set()
    path = Path(args.out)
    if path.exists():
        rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        done = {r["seed"] for r in rows}
    with tempfile.TemporaryDirectory() as tmp, path.open("a") as fh:
        for seed in range(args.first, args.first + args.seeds):
            if seed in done:
                continue
            with tempfile.TemporaryDirectory(dir=tmp) as one_tmp:
                row = one(seed, Path(one_tmp))
            rows.append(row)
            fh.write(json.dumps(row) + "\n")
            fh.flush()
    print(summary(rows))


if __name__ == "__main__":
    main()
