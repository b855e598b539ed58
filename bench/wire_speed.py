"""Messages per second through bvm.wire's encoder and decoder, on a realistic traffic mix.

    python bench/wire_speed.py [--repeat N] [--messages M] [--seed S]

The mix imitates what ROSBuzz scripts put on the air every step (docs/wire-format.md#message-types,
docs/bundle.md#commands-on-the-radio):
broadcasts of a command code, of one float and of small tables (velocities, graph
formation state); stigmergy PUTs and QUERYs with string keys (status, barrier) and int
keys (waypoints); swarm LIST/JOIN. Each direction runs over the whole mix, best of N.
"""

from __future__ import annotations

import argparse
import collections
import random
import time
from collections.abc import Callable

from bvm import wire
from bvm.values import Table, f32


def traffic(n: int, seed: int) -> list[wire.Message]:
    """n messages drawn from the mix."""
    rng = random.Random(seed)

    def coord() -> float:
        return f32(rng.uniform(-50.0, 50.0))

    makers: list[tuple[float, Callable[[], wire.Message]]] = [
        (10, lambda: wire.Broadcast("cmd", rng.choice((22, 21, 20, 900, 901, 904)))),
        (10, lambda: wire.Broadcast("f", coord())),
        (15, lambda: wire.Broadcast(f"v{rng.randrange(10)}", Table(x=coord(), y=coord()))),
        (
            10,
            lambda: wire.Broadcast(
                "m", Table(id=rng.randrange(10), state=rng.randrange(4), lock=0, dist=coord())
            ),
        ),
        (
            20,
            lambda: wire.VstigPut(
                20,
                f"s{rng.randrange(10)}",
                Table(battery=f32(rng.uniform(10, 16)), state="TURNEDOFF", alt=coord()),
                rng.randrange(1, 500),
                rng.randrange(10),
            ),
        ),
        (
            10,
            lambda: wire.VstigPut(
                80, rng.randrange(10), 900, rng.randrange(1, 50), rng.randrange(10)
            ),
        ),
        (5, lambda: wire.VstigPut(8, rng.randrange(10), rng.randrange(1 << 30), 3, 1)),
        (10, lambda: wire.VstigQuery(80, "n", None, 0, rng.randrange(10))),
        (5, lambda: wire.VstigQuery(20, f"s{rng.randrange(10)}", None, 0, rng.randrange(10))),
        (4, lambda: wire.SwarmList(tuple(sorted(rng.sample(range(1, 10), rng.randrange(1, 4)))))),
        (1, lambda: wire.SwarmJoin(1)),
    ]
    weights = [w for w, _ in makers]
    funcs = [f for _, f in makers]
    return [rng.choices(funcs, weights)[0]() for _ in range(n)]


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    """The shortest of `repeat` timed runs of fn, in seconds."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--messages", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)

    msgs = traffic(args.messages, args.seed)
    payloads = [wire.encode(m) for m in msgs]
    assert [wire.decode(p) for p in payloads] == msgs  # the bench measures correct code
    encode, decode = wire.encode, wire.decode

    def enc_all() -> None:
        for m in msgs:
            encode(m)

    def dec_all() -> None:
        for p in payloads:
            decode(p)

    n = len(msgs)
    kinds = collections.Counter(m.type.name for m in msgs)
    size = sum(map(len, payloads)) / n
    print(f"{n} messages, {size:.1f} bytes on average: {dict(kinds)}")
    t_enc = best_of(args.repeat, enc_all)
    t_dec = best_of(args.repeat, dec_all)
    print(f"encode: {n / t_enc:10,.0f} messages/s  ({t_enc / n * 1e6:.2f} us each)")
    print(f"decode: {n / t_dec:10,.0f} messages/s  ({t_dec / n * 1e6:.2f} us each)")
    print(f"(best of {args.repeat})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
