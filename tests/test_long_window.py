"""Windows of hours in bounded memory: samples travel as numpy columns, never one object each.

The memory test is not timed: it compares tracemalloc's peak of an in-process ``find_north`` on
the embedded simulator (virtual clock) with short and long windows. The collector's block path
is checked against its one-sample path on streams with gaps, repeats, wraps, losses and restarts.
"""

from __future__ import annotations

import dataclasses
import gc
import tracemalloc

import numpy as np
import pytest

from northfinder.driver.errors import DeviceReset, StreamGap
from northfinder.driver.protocol.can import TickLoss
from northfinder.driver.protocol.constants import TEMPERATURE_NOT_AVAILABLE, Validity
from northfinder.driver.protocol.messages import Sample
from northfinder.driver.window import (
    _ARRAYS,
    CountScales,
    SampleColumns,
    SampleInbox,
    WindowCollector,
)
from northfinder.embed import SimulatedInstrument
from northfinder.host import procedure, recording
from northfinder.host.procedure import Plan, find_north
from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording, RecordingWriter

U32 = 1 << 32
RATE_HZ = 200


def _sample(rng: np.random.Generator, counter: int) -> Sample:
    temp = int(rng.integers(-3000, 8000)) if rng.random() > 0.1 else TEMPERATURE_NOT_AVAILABLE
    g, a = rng.integers(-(2**31), 2**31, 3), rng.integers(-(2**23), 2**23, 3)
    return Sample(
        counter % U32,
        (int(g[0]), int(g[1]), int(g[2])),
        (int(a[0]), int(a[1]), int(a[2])),
        int(rng.integers(0, 360_000_000)),
        temp,
        Validity(int(rng.integers(0, 256))),
    )


def _stream(seed: int) -> list[tuple[str, object, float]]:
    """Samples and losses as a link may deliver them: runs of consecutive ticks broken by
    gaps, repeats, losses (some overlapping samples that still come), a wrap of the counter and,
    sometimes, a restart."""
    rng = np.random.default_rng(seed)
    c = int(rng.choice([0, U32 - 300, 123_456]))
    items: list[tuple[str, object, float]] = []
    t = 1000.0
    for _ in range(rng.integers(5, 40)):
        for _ in range(rng.integers(1, 120)):
            items.append(("sample", _sample(rng, c), t))
            c, t = c + 1, t + 0.005
        r = rng.random()
        if r < 0.25:
            c += int(rng.integers(1, 5))  # a gap
        elif r < 0.4:
            items.append(("sample", _sample(rng, c - 1), t))  # a repeat
        elif r < 0.6:
            n = int(rng.integers(1, 6))
            start = c - int(rng.integers(0, 3))
            items.append(("loss", TickLoss(start % U32, n, n == 1), t))
            c = max(c, start + n) if rng.random() < 0.5 else c
        elif r < 0.63:
            c -= int(rng.integers(5, 50))  # a restart
    return items


def _one_by_one(items, requested, on_gap):
    col = WindowCollector(requested, on_gap=on_gap)
    try:
        for kind, item, t in items:
            if kind == "loss":
                col.add_loss(item)
            elif col.add_sample(item, t):
                break
        error = None
    except (StreamGap, DeviceReset) as exc:
        error = (type(exc), str(exc))
    return col, error


def _in_blocks(items, requested, on_gap, chunk):
    """As a device feeds it: through the inbox, taken in blocks of ``chunk`` items."""
    col = WindowCollector(requested, on_gap=on_gap)
    inbox = SampleInbox(chunk=7)
    try:
        for k in range(0, len(items), chunk):
            for kind, item, t in items[k : k + chunk]:
                if kind == "loss":
                    inbox.add_event("loss", item, t, t)
                else:
                    inbox.add_sample(item, t, t)
            block, events = inbox.take()
            pos = 0
            done = False
            for before, _kind, item, _m, _w in events:
                if before > pos and col.add_samples(block, pos, before):
                    done = True
                    break
                pos = before
                col.add_loss(item)
            if done or (pos < len(block) and col.add_samples(block, pos, len(block))):
                break
        error = None
    except (StreamGap, DeviceReset) as exc:
        error = (type(exc), str(exc))
    return col, error


@pytest.mark.parametrize("seed", range(40))
def test_blocks_collect_what_one_sample_at_a_time_collects(seed):
    items = _stream(seed)
    rng = np.random.default_rng(1000 + seed)
    requested = int(rng.integers(1, 1500))
    on_gap = "report" if seed % 3 else "raise"
    chunk = int(rng.choice([1, 5, 64, 10_000]))
    a, err_a = _one_by_one(items, requested, on_gap)
    b, err_b = _in_blocks(items, requested, on_gap, chunk)
    assert err_a == err_b
    assert (a.received, a.missing, a.gaps, a.done) == (b.received, b.missing, b.gaps, b.done)
    scales = CountScales()
    if a.received:
        wa, wb = a.window(RATE_HZ, scales), b.take_window(RATE_HZ, scales)  # as a device does
        for name in _ARRAYS:
            x, y = getattr(wa, name), getattr(wb, name)
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y, err_msg=name)


def test_window_in_units_matches_the_samples():
    rng = np.random.default_rng(5)
    samples = [_sample(rng, 10 + k) for k in range(50)]
    col = WindowCollector(50)
    for k, s in enumerate(samples):
        col.add_sample(s, 2.0 + k)
    w = col.window(RATE_HZ, CountScales())
    cols = SampleColumns.of(samples, [2.0 + k for k in range(50)])
    np.testing.assert_array_equal(w.gyro_dph, np.array([s.gyro for s in samples]) * 1e-4)
    np.testing.assert_array_equal(w.counter, cols.counter)
    nan = np.array([s.temperature == TEMPERATURE_NOT_AVAILABLE for s in samples])
    np.testing.assert_array_equal(np.isnan(w.temperature_c), nan)
    np.testing.assert_array_equal(w.validity, [int(s.validity) for s in samples])


def test_the_inbox_holds_columns_not_samples():
    rng = np.random.default_rng(2)
    inbox = SampleInbox(chunk=16)
    for k in range(100):
        inbox.add_sample(_sample(rng, k), float(k), float(k))
    inbox.add_event("loss", TickLoss(100, 2, False), 100.0, 100.0)
    assert len(inbox) == 101
    assert len(inbox._samples) == 100 % 16  # the rest are columns already
    block, events = inbox.take()
    assert len(block) == 100 and events[0][:2] == (100, "loss") and len(inbox) == 0
    np.testing.assert_array_equal(block.counter, np.arange(100))


def _find_peak_bytes(window_s: float) -> tuple[int, int]:
    """tracemalloc's peak during a two-position find with ``window_s`` windows, and the samples."""
    with (
        SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready(5.0)
        gc.collect()
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            result, raw = find_north(dev, Plan((0.0, 90.0), window_s), 34.0)
            peak = tracemalloc.get_traced_memory()[1] - base
        finally:
            tracemalloc.stop()
    assert result.azimuth_deg == pytest.approx(sim.truth.azimuth_deg, abs=0.01)
    return peak, sum(len(w) for w in raw)


@pytest.mark.parametrize("block", [1, 2, 7, 1 << 16])
def test_the_encoder_is_unwrapped_as_numpy_unwraps_it(monkeypatch, block):
    monkeypatch.setattr(procedure, "_UNWRAP_BLOCK", block)
    rng = np.random.default_rng(block)
    for k in range(60):
        n = int(rng.integers(0, 2000))
        near = rng.choice([0.0, 359.995, 180.0, 0.003])
        x = (near + rng.normal(0, rng.choice([0.001, 0.01, 5.0, 200.0]), n)) % 360
        if k % 7 == 0:
            x = np.cumsum(rng.normal(0, 100, n)) % 360  # turning: many wraps
        if k % 11 == 0 and n > 3:
            x[1], x[2] = x[0] + 180.0, x[0]  # differences of exactly half a turn
        expected = np.degrees(np.unwrap(np.radians(x)))
        np.testing.assert_array_equal(procedure._unwrap_deg(x), expected)


def test_memory_per_sample_of_a_find_is_bounded():
    """Ten times the window costs about its arrays more, not an object per sample (about 440
    bytes a sample before): 89 bytes a sample kept in physical units, and the window check's
    temporaries (about 50 bytes a sample of the window in hand; 25 over two windows)."""
    _find_peak_bytes(0.5)  # what the first find of a process sets up once (imports, caches)
    short, n_short = _find_peak_bytes(15.0)
    long, n_long = _find_peak_bytes(150.0)
    assert n_long - n_short == 2 * 135 * RATE_HZ
    per_sample = (long - short) / (n_long - n_short)
    assert per_sample < 125, f"{per_sample:.0f} bytes a sample"


def _recording_peak_bytes(tmp_path, positions: int, keep: bool) -> tuple[int, int]:
    """tracemalloc's peak during a find of ``positions`` 20 s windows written to an NPZ as they
    end (``keep``: the windows also kept), and the samples written."""
    plan = Plan(tuple(90.0 * (k % 4) for k in range(positions)), 20.0)
    path = tmp_path / f"run{positions}{keep}.npz"
    with (
        SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready(5.0)
        writer = RecordingWriter(path, {"sample_rate_hz": RATE_HZ}, keep_windows=keep)

        def write(i: int, window) -> None:
            writer.add(RecordedWindow.from_window(window, plan.positions_deg[i]))

        gc.collect()
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            _, raw = find_north(dev, plan, 34.0, on_window=write, keep_windows=keep)
            peak = tracemalloc.get_traced_memory()[1] - base
        finally:
            tracemalloc.stop()
        writer.close("complete")
    assert len(raw) == len(writer.windows) == (positions if keep else 0)
    assert [len(w.counter) for w in Recording.load(path).windows] == writer.sizes
    assert set(writer.sizes) == {20 * RATE_HZ}
    return peak, sum(writer.sizes)


def test_windows_not_kept_cost_no_memory_as_the_plan_grows(tmp_path):
    """A run writing its windows and keeping none (``record``, ``find`` without a plot) holds one
    window's samples at a time: four times the windows, about the same peak; kept, each
    sample added costs its arrays (the control: the measure sees them)."""
    _recording_peak_bytes(tmp_path, 4, False)  # what a first run sets up once (imports, caches)
    grown = {}
    for keep in (False, True):
        few, n_few = _recording_peak_bytes(tmp_path, 4, keep)
        many, n_many = _recording_peak_bytes(tmp_path, 24, keep)
        grown[keep] = (many - few) / (n_many - n_few)
    assert grown[True] > 60, f"kept: {grown[True]:.1f} bytes a sample more for more windows"
    assert grown[False] < 30, f"not kept: {grown[False]:.1f} bytes a sample more"


class _CutOff:
    """A column whose row ``at`` cannot be read: the run is interrupted while it is written."""

    def __init__(self, a: np.ndarray, at: int) -> None:
        self.a, self.at = a, at

    def __len__(self) -> int:
        return len(self.a)

    def __getitem__(self, j):
        if j == self.at:
            raise KeyboardInterrupt
        return self.a[j]


def _recorded(n: int, first: int, commanded: float) -> RecordedWindow:
    counter = np.arange(first, first + n, dtype=np.int64)
    return RecordedWindow(
        commanded,
        counter,
        counter / RATE_HZ,
        np.tile([1.0, 2.0, 3.0], (n, 1)),
        np.tile([0.0, 0.0, 9.8], (n, 1)),
        np.full(n, commanded),
        np.full(n, 20.0),
        np.full(n, 3, dtype=np.uint8),
    )


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_long_window_recorded_in_blocks_round_trips(tmp_path, monkeypatch, suffix):
    monkeypatch.setattr(recording, "_CSV_BLOCK_ROWS", 7)
    monkeypatch.setattr(recording, "_NPZ_CHUNK_BYTES", 100)
    windows = (_recorded(50, 10, 0.0), _recorded(33, 200, 90.0))
    writer = RecordingWriter(
        tmp_path / f"run{suffix}", {"latitude_deg": 34.0, "sample_rate_hz": RATE_HZ}
    )
    for w in windows:
        writer.add(w)
    writer.close()
    back = Recording.load(tmp_path / f"run{suffix}")
    assert len(back.windows) == 2
    for a, b in zip(windows, back.windows, strict=True):
        for name in SAMPLE_ARRAYS:
            np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=0, atol=1e-6)


@pytest.mark.parametrize("complete", [0, 1])
def test_a_csv_window_cut_off_between_blocks_leaves_complete_windows(
    tmp_path, monkeypatch, complete
):
    monkeypatch.setattr(recording, "_CSV_BLOCK_ROWS", 10)
    path = tmp_path / "run.csv"
    writer = RecordingWriter(path, {"latitude_deg": 34.0, "sample_rate_hz": RATE_HZ})
    for k in range(complete):
        writer.add(_recorded(40, 100 * k, 0.0))
    cut = _recorded(40, 100 * complete, 90.0)
    # Cut off after two blocks of rows were written.
    cut = dataclasses.replace(cut, gyro_dph=_CutOff(cut.gyro_dph, 25))  # type: ignore[arg-type]
    with pytest.raises(KeyboardInterrupt):
        writer.add(cut)
    writer.close("interrupted")
    rows = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    assert len(rows) == 1 + 40 * complete  # the column names, and the complete windows' rows
    if complete:
        back = Recording.load(path, min_windows=1)
        assert back.status == "interrupted" and len(back.windows) == 1
        np.testing.assert_array_equal(back.windows[0].counter, np.arange(40))
