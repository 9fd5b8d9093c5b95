"""Link budget: the load the periodic traffic puts on a link, and which sample rates fit.

The device refuses (RATE_EXCEEDS_LINK) any sample rate or heartbeat period whose periodic
traffic does not fit: on CAN the worst-case (maximally bit-stuffed) load must stay at or below
50 % of the bit rate; on serial the bytes (10 bits each, 8N1) at or below 80 % of the baud rate.
"""

from __future__ import annotations

from northfinder.driver.protocol.constants import HEARTBEAT_PERIOD_DEFAULT_MS, SAMPLE_RATES_HZ
from northfinder.driver.protocol.errors import ArgumentError
from northfinder.driver.protocol.messages import Sample, Status
from northfinder.driver.protocol.serial import CRC_SIZE, HEADER_SIZE

__all__ = [
    "CAN_LOAD_LIMIT",
    "SERIAL_LOAD_LIMIT",
    "can_bus_load",
    "can_frame_bits",
    "max_sample_rate",
    "rate_fits",
    "serial_bytes_per_second",
    "serial_load",
]

CAN_LOAD_LIMIT = 0.5
"""Largest worst-case CAN bus load the device's periodic traffic may take."""
SERIAL_LOAD_LIMIT = 0.8
"""Largest fraction of the serial line the device's periodic traffic may take."""

SAMPLE_FRAMES_PER_TICK = 4
STATUS_FRAMES = 2
CAN_DLC = 8
SERIAL_SAMPLE_FRAME = HEADER_SIZE + Sample.SIZE + CRC_SIZE
SERIAL_STATUS_FRAME = HEADER_SIZE + Status.SIZE + CRC_SIZE
SERIAL_BITS_PER_BYTE = 10


def can_frame_bits(dlc: int, worst_case: bool = True) -> int:
    """Bits on the bus for one CAN 2.0A data frame, including the 3-bit interframe space.

    Parameters
    ----------
    dlc : int
        Data bytes, 0..8.
    worst_case : bool
        Add the largest possible number of stuff bits (one per four bits after the first
        over SOF .. CRC).

    Returns
    -------
    int
        47 + 8 dlc bits, plus ``(34 + 8 dlc - 1) // 4`` stuff bits in the worst case
        (111 and 135 bits for 8 bytes).
    """
    bits = 47 + 8 * dlc
    if worst_case:
        bits += (34 + 8 * dlc - 1) // 4
    return bits


def can_bus_load(
    bitrate: int,
    sample_rate_hz: float,
    heartbeat_period_ms: float = HEARTBEAT_PERIOD_DEFAULT_MS,
    worst_case: bool = True,
) -> float:
    """Fraction of a CAN bus taken by the sample stream and the heartbeat of one device.

    Parameters
    ----------
    bitrate : int
        Bus bit rate in bit/s.
    sample_rate_hz : float
        Sample rate (four 8-byte frames per tick); 0 when not streaming.
    heartbeat_period_ms : float
        Heartbeat period (two 8-byte frames per period).
    worst_case : bool
        Count the worst-case stuff bits.

    Returns
    -------
    float
        Load, 1.0 = saturated.
    """
    frames_per_s = SAMPLE_FRAMES_PER_TICK * sample_rate_hz + STATUS_FRAMES * 1000.0 / (
        heartbeat_period_ms
    )
    return frames_per_s * can_frame_bits(CAN_DLC, worst_case) / bitrate


def serial_bytes_per_second(
    sample_rate_hz: float, heartbeat_period_ms: float = HEARTBEAT_PERIOD_DEFAULT_MS
) -> float:
    """Bytes per second the device sends on serial for samples and heartbeat."""
    return sample_rate_hz * SERIAL_SAMPLE_FRAME + 1000.0 / heartbeat_period_ms * SERIAL_STATUS_FRAME


def serial_load(
    baud: int, sample_rate_hz: float, heartbeat_period_ms: float = HEARTBEAT_PERIOD_DEFAULT_MS
) -> float:
    """Fraction of a serial line (8N1: 10 bits a byte) taken by samples and heartbeat."""
    return (
        serial_bytes_per_second(sample_rate_hz, heartbeat_period_ms) * SERIAL_BITS_PER_BYTE / baud
    )


def rate_fits(
    link: str,
    bitrate: int,
    sample_rate_hz: float,
    heartbeat_period_ms: float = HEARTBEAT_PERIOD_DEFAULT_MS,
) -> bool:
    """Whether a sample rate and heartbeat period fit a link by the device's rule.

    Parameters
    ----------
    link : {"can", "serial"}
        Link kind.
    bitrate : int
        CAN bit rate or serial baud rate.
    sample_rate_hz, heartbeat_period_ms : float
        The configuration to check.

    Raises
    ------
    ArgumentError
        Unknown ``link`` (the message lists the choices).
    """
    if link == "can":
        return can_bus_load(bitrate, sample_rate_hz, heartbeat_period_ms) <= CAN_LOAD_LIMIT
    if link == "serial":
        return serial_load(bitrate, sample_rate_hz, heartbeat_period_ms) <= SERIAL_LOAD_LIMIT
    raise ArgumentError(f"link={link!r}: choose 'can' or 'serial'")


def max_sample_rate(
    link: str, bitrate: int, heartbeat_period_ms: float = HEARTBEAT_PERIOD_DEFAULT_MS
) -> int:
    """Highest allowed sample rate that fits the link, or 0 if none does."""
    fitting = [r for r in SAMPLE_RATES_HZ if rate_fits(link, bitrate, r, heartbeat_period_ms)]
    return max(fitting, default=0)
