"""``codec``: random and mutated input into every decoder (a section of ``bench_robustness.py``)."""

from __future__ import annotations

import argparse
import random
from collections.abc import Callable
from functools import partial
from typing import Any

from northfinder.driver.protocol.constants import Validity
from northfinder.driver.protocol.messages import Sample
from northfinder.driver.protocol.serial import Deframer, SerialEncoder


def _sample_frames(rng: random.Random, count: int, seq0: int = 0) -> list[bytes]:

    enc = SerialEncoder(seq0)

    def i32() -> int:
        return rng.randrange(-(2**31), 2**31)

    return [
        enc.encode(
            Sample(
                rng.randrange(2**32),
                (i32(), i32(), i32()),
                (i32(), i32(), i32()),
                rng.randrange(2**32),
                rng.randrange(-(2**15), 2**15),
                Validity(rng.randrange(256)),
            )
        )
        for _ in range(count)
    ]


def codec_fuzz(args: argparse.Namespace) -> dict[str, Any]:
    """Random and mutated input into every decoder; what is not a typed error, and what
    resynchronisation loses."""
    from northfinder.driver.errors import ProtocolError
    from northfinder.driver.protocol import (
        Command,
        Identify,
        IdentifyPage,
        Reply,
        SampleAux,
        SampleX,
        Status,
        StatusCounters,
        StatusMain,
    )  # fmt: skip
    from northfinder.driver.protocol.can import CanReceiver, decode_can

    rng = random.Random(args.seed)
    n = args.fuzz_inputs
    untyped: dict[str, int] = {}
    counts: dict[str, int] = {}

    def guard(name: str, call: Callable[[], Any]) -> None:
        counts[name] = counts.get(name, 0) + 1
        try:
            call()
        except ProtocolError:
            pass
        except Exception:
            untyped[name] = untyped.get(name, 0) + 1

    types: list[Any] = [Command, Reply, Sample, SampleX, SampleAux, Status, StatusMain, StatusCounters,
             Identify, IdentifyPage]  # fmt: skip
    for _ in range(n):
        kind = types[rng.randrange(len(types))]
        data = rng.randbytes(rng.randrange(0, 80))
        guard("payload decoders", partial(kind.decode, data))
    receiver = CanReceiver(node_id=1)
    for _ in range(n):
        ident = rng.choice([rng.randrange(0x800), 0x100 + rng.randrange(0x100)])
        data = rng.randbytes(rng.randrange(0, 9))
        guard("CAN frames (decode_can)", partial(decode_can, ident, data))
        guard("CAN frames (CanReceiver)", partial(receiver.feed, ident, data))
    deframer = Deframer()
    chunks = 0
    for _ in range(n // 10):
        data = rng.randbytes(rng.randrange(1, 200))
        guard("serial bytes (Deframer)", partial(deframer.feed_messages, data))
        chunks += 1
    # Resynchronisation: a frame, a mutated frame, then the stream goes on; the frame before
    # and the two after the mutated one must come through.
    mutations = (
        "delete a byte",
        "flip a byte",
        "insert a byte",
        "truncate",
        "last byte lost (0xA5)",
    )
    lost = {m: 0 for m in mutations}
    false = {m: 0 for m in mutations}  # damaged frames that passed the CRC
    trials = {m: 0 for m in mutations}
    # The case the CRC cannot see: a frame whose CRC high byte is A5 loses it, and the next
    # frame's first sync byte completes it (one frame in 256 has such a CRC).
    a5_pool = [f for f in _sample_frames(rng, 256 * 64) if f[-1] == 0xA5]
    for t in range(args.fuzz_frames):
        how = mutations[t % len(mutations)]
        if how == "last byte lost (0xA5)":
            frames = _sample_frames(rng, 5, rng.randrange(256))
            frames[1] = a5_pool[rng.randrange(len(a5_pool))]
            middle = frames[1][:-1]
        else:
            frames = _sample_frames(rng, 5, rng.randrange(256))
            b = bytearray(frames[1])
            k = rng.randrange(len(b))
            if how == "delete a byte":
                del b[k]
            elif how == "flip a byte":
                b[k] ^= 1 << rng.randrange(8)
            elif how == "insert a byte":
                b.insert(k, rng.randrange(256))
            else:
                del b[k:]
            middle = bytes(b)
        d = Deframer()
        # two more frames after them, as a stream goes on (a false candidate may wait for them)
        got = [f.payload for f in d.feed(frames[0] + middle + b"".join(frames[2:]))]
        want = [frames[0][5:-2], frames[2][5:-2], frames[3][5:-2]]
        trials[how] += 1
        lost[how] += sum(1 for w in want if w not in got)
        false[how] += sum(1 for g in got if g not in (*want, frames[1][5:-2], frames[4][5:-2]))
    print(f"codec fuzz (seed {args.seed}): inputs and exceptions other than ProtocolError")
    for name, count in counts.items():
        print(f"  {name:<28} {count:>9} inputs   {untyped.get(name, 0)} untyped exceptions")
    print("resynchronisation: frame, mutated frame, frames; good frames lost, damaged frames "
          "delivered (passed the CRC)")  # fmt: skip
    for how in mutations:
        print(f"  {how:<28} {trials[how]:>9} trials   {lost[how]} good frames lost   "
              f"{false[how]} damaged frames delivered")  # fmt: skip
    return {"inputs": counts, "untyped": untyped, "resync_trials": trials, "resync_lost": lost,
            "damaged_delivered": false}  # fmt: skip
