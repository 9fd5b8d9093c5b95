"""The window collector on constructed inputs: no link, no thread, no clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from northfinder.driver.errors import (
    ArgumentError,
    DeviceReset,
    DriverError,
    EmptyWindow,
    StreamGap,
)
from northfinder.driver.protocol.can import TickLoss
from northfinder.driver.protocol.constants import TEMPERATURE_NOT_AVAILABLE, Validity
from northfinder.driver.protocol.messages import Sample
from northfinder.driver.protocol.units import DPH, G0
from northfinder.driver.window import CountScales, WindowCollector

GOOD = Validity.GYRO_VALID | Validity.ACCEL_VALID
U32 = 1 << 32


def sample(counter: int, validity: int = GOOD, gyro: int = 10) -> Sample:
    """A sample whose channels encode its counter, so rows can be told apart."""
    return Sample(
        counter % U32,
        (gyro, -gyro, counter % 1000),
        (1, 2, 1_000_000),
        counter % 360_000_000,
        2500,
        Validity(validity),
    )


def feed(collector: WindowCollector, counters: list[int]) -> None:
    for c in counters:
        collector.add_sample(sample(c), arrival_s=float(c))


def test_contiguous_window_in_physical_units():
    col = WindowCollector(4)
    assert not col.done
    assert [col.add_sample(sample(c), float(c)) for c in (100, 101, 102, 103)] == [
        False,
        False,
        False,
        True,
    ]
    w = col.window(200.0, CountScales())
    assert w.complete and w.missing == 0 and w.gaps == () and len(w) == 4 == w.requested
    np.testing.assert_array_equal(w.counter, [100, 101, 102, 103])
    np.testing.assert_allclose(w.time_s, np.array([100, 101, 102, 103]) / 200.0, rtol=0, atol=0)
    np.testing.assert_array_equal(w.arrival_s, [100.0, 101.0, 102.0, 103.0])
    np.testing.assert_allclose(w.gyro_dph[0], [10e-4, -10e-4, 100e-4], rtol=1e-15)
    np.testing.assert_allclose(w.accel_mps2[0], np.array([1, 2, 1e6]) * 1e-6 * G0, rtol=1e-15)
    np.testing.assert_allclose(w.table_deg, np.array([100, 101, 102, 103]) * 1e-6, rtol=1e-15)
    np.testing.assert_allclose(w.temperature_c, 25.0)
    np.testing.assert_allclose(w.gyro_rps, w.gyro_dph * DPH, rtol=1e-15)
    assert w.duration_s == pytest.approx(0.02)
    assert w.counter.dtype == np.int64 and w.validity.dtype == np.uint8
    for name in ("counter", "time_s", "gyro_dph", "accel_mps2", "validity"):
        with pytest.raises(ValueError):
            getattr(w, name)[0] = 0  # read-only


def test_scales_of_the_unit_apply():
    col = WindowCollector(1)
    col.add_sample(sample(7), 0.0)
    scales = CountScales(gyro_dph=2.0, accel_mps2=3.0, angle_deg=4.0, temperature_c=0.5)
    w = col.window(100.0, scales)
    np.testing.assert_array_equal(w.gyro_dph[0], [20.0, -20.0, 14.0])
    np.testing.assert_array_equal(w.accel_mps2[0], [3.0, 6.0, 3e6])
    assert w.table_deg[0] == 28.0 and w.temperature_c[0] == 1250.0


def test_temperature_without_reading_is_nan():
    col = WindowCollector(1)
    s = sample(1)
    col.add_sample(Sample(1, s.gyro, s.accel, 0, TEMPERATURE_NOT_AVAILABLE, GOOD), 0.0)
    assert math.isnan(col.window(200.0, CountScales()).temperature_c[0])
    assert math.isnan(CountScales().temperature(TEMPERATURE_NOT_AVAILABLE))


def test_gaps_are_reported_with_their_counters():
    col = WindowCollector(8, on_gap="report")
    feed(col, [10, 11, 14, 15, 16])
    assert not col.done
    feed(col, [20])  # beyond the end (10 + 8 = 18): the window ends with 17 missing
    assert col.done
    w = col.window(200.0, CountScales())
    np.testing.assert_array_equal(w.counter, [10, 11, 14, 15, 16])
    assert w.gaps == ((12, 2), (17, 1)) and w.missing == 3 and not w.complete
    assert len(w) + w.missing == w.requested


def test_a_gap_raises_at_once_with_what_was_received():
    col = WindowCollector(8)
    feed(col, [10, 11])
    with pytest.raises(StreamGap, match="2 sample tick\\(s\\) missing from counter 12") as info:
        col.add_sample(sample(14), 0.0)
    assert info.value.gaps == ((12, 2),) and info.value.missing == 2 and info.value.received == 2
    assert isinstance(info.value, DriverError)


def test_counter_continues_past_the_wrap():
    col = WindowCollector(5, on_gap="report")
    feed(col, [U32 - 2, U32 - 1, U32 + 1, U32 + 2])  # U32 + 0 (counter 0) lost
    w = col.window(200.0, CountScales())
    np.testing.assert_array_equal(w.counter, [U32 - 2, U32 - 1, U32 + 1, U32 + 2])
    assert w.gaps == ((U32, 1),) and col.done


def test_tick_losses_are_counted_once_and_clipped_to_the_window():
    col = WindowCollector(10, on_gap="report")
    assert not col.add_loss(TickLoss(3, 4, False))  # before the window: not its business
    feed(col, [10, 11])
    col.add_loss(TickLoss(12, 3, False))  # 12, 13, 14 lost on the link ...
    feed(col, [15])  # ... then 15 arrives: no second gap for them
    col.add_loss(TickLoss(16, 1, True))  # an incomplete CAN tick
    feed(col, [17])
    assert col.add_loss(TickLoss(18, 50, False))  # runs past the end: the window is done
    w = col.window(200.0, CountScales())
    assert w.gaps == ((12, 3), (16, 1), (18, 2)) and w.missing == 6
    np.testing.assert_array_equal(w.counter, [10, 11, 15, 17])


def test_a_loss_across_the_wrap():
    col = WindowCollector(6, on_gap="report")
    feed(col, [U32 - 2, U32 - 1])
    col.add_loss(
        TickLoss(0, 2, False)
    )  # the device's counters 0 and 1 = window counters 2**32 + 0, 1
    feed(col, [U32 + 2, U32 + 3])
    assert col.done
    assert col.window(200.0, CountScales()).gaps == ((U32, 2),)


def test_loss_of_the_last_ticks_ends_the_window():
    col = WindowCollector(3)
    feed(col, [5])
    with pytest.raises(StreamGap):
        col.add_loss(TickLoss(6, 2, False))
    col = WindowCollector(3, on_gap="report")
    feed(col, [5, 6])
    assert col.add_loss(TickLoss(7, 1, True))


def test_repeated_sample_is_ignored_and_counter_going_back_is_a_reset():
    col = WindowCollector(4)
    feed(col, [50, 51, 51, 52])
    assert col.received == 3 and not col.done
    with pytest.raises(DeviceReset, match="went back from 52 to 3 after 3 of 4"):
        col.add_sample(sample(3), 0.0)


def test_first_sample_may_be_anywhere():
    col = WindowCollector(2)
    feed(col, [U32 - 1, U32])  # the device's counter 0 follows 2**32 - 1
    np.testing.assert_array_equal(col.window(200.0, CountScales()).counter, [U32 - 1, U32])


def test_valid_mask_and_mean():
    col = WindowCollector(4)
    validity = [GOOD, GOOD | Validity.TABLE_SETTLING, Validity.GYRO_VALID, GOOD]
    for c, v in zip((1, 2, 3, 4), validity, strict=True):
        col.add_sample(sample(c, v, gyro=10 * c), 0.0)
    w = col.window(200.0, CountScales())
    np.testing.assert_array_equal(w.valid_mask, [True, False, False, True])
    gyro, accel = w.mean()
    np.testing.assert_allclose(gyro[0], (10 + 40) / 2 * 1e-4, rtol=1e-12)
    np.testing.assert_allclose(accel[2], G0, rtol=1e-12)
    gyro_all, _ = w.mean(valid_only=False)
    np.testing.assert_allclose(gyro_all[0], 25 * 1e-4, rtol=1e-12)


def test_empty_window_has_no_mean():
    col = WindowCollector(2)
    for c in (1, 2):
        col.add_sample(sample(c, Validity.WARMING_UP), 0.0)
    w = col.window(200.0, CountScales())
    with pytest.raises(EmptyWindow, match="no valid sample"):
        w.mean()
    with pytest.raises(ValueError, match="holds no sample"):
        WindowCollector(1).window(200.0, CountScales()).mean(valid_only=False)


def test_bad_arguments_name_the_choices():
    with pytest.raises(ArgumentError, match="'raise', 'report'"):
        WindowCollector(3, on_gap="ignore")  # type: ignore[arg-type]
    with pytest.raises(ArgumentError, match="requested=0"):
        WindowCollector(0)
