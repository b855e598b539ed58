"""What sealing and verifying a bundle costs, against encoding and decoding it, in one run.

    python bench/auth_cost.py [--bundles N] [--repeat R] [--seed S]

N bundles of a realistic spread of sizes (an empty step, a few small Buzz messages, a full
sealed budget of 180 bytes) are encoded (`bundle.encode_fields`), decoded (`bundle.decode`),
sealed (`Sealer.seal`: a counter, HMAC-SHA256) and verified (`Verifier.verify`: the checks,
HMAC-SHA256, the replay window) in the same process, best of R runs each. Reported: the time
per bundle of each, the ratios seal/encode and verify/decode (what authentication adds to
the work a robot does per bundle anyway), and the bytes the trailer adds, against the mean
and the largest bundle. The ratios, not the microseconds, are what carries to a robot's CPU.
"""

from __future__ import annotations

import argparse
import random
import time
from collections.abc import Callable

from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A


def bundles(n: int, seed: int) -> list[tuple[int, tuple[bytes, ...]]]:
    """n (robot, messages) pairs: a third empty steps, a third small, a third full."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        kind = i % 3
        if kind == 0:
            messages: tuple[bytes, ...] = ()
        elif kind == 1:
            messages = tuple(rng.randbytes(rng.randint(3, 24)) for _ in range(rng.randint(1, 4)))
        else:
            messages = (rng.randbytes(A.SEALED_MAX_BUZZ_BYTES - B.MSG_OVERHEAD),)
        out.append((7, messages))
    return out


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    """The shortest of `repeat` timed runs of fn, in seconds."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(n: int, repeat: int, seed: int) -> dict[str, float]:
    """Seconds per bundle of encode, decode, seal and verify, and the bytes figures."""
    items = bundles(n, seed)
    key = A.bundle_key(bytes(range(32)))
    airs = [B.encode_fields(r, m, 45.5, -73.6, 10.0, i, i) for i, (r, m) in enumerate(items)]
    sealer = A.Sealer(7, key, A.MemoryCounter())
    sealed = [sealer.seal(a) for a in airs]
    check = A.Verifier(key)
    assert [check.verify(s) for s in sealed] == airs  # the bench measures correct code
    encode, decode = B.encode_fields, B.decode

    def enc_all() -> None:
        for i, (r, m) in enumerate(items):
            encode(r, m, 45.5, -73.6, 10.0, i, i)

    def dec_all() -> None:
        for a in airs:
            decode(a)

    def seal_all() -> None:
        s = A.Sealer(7, key, A.MemoryCounter())
        for a in airs:
            s.seal(a)

    def verify_all() -> None:
        v = A.Verifier(key)  # a fresh window each run: every bundle is accepted
        for s in sealed:
            v.verify(s)

    return {
        "encode": best_of(repeat, enc_all) / n,
        "decode": best_of(repeat, dec_all) / n,
        "seal": best_of(repeat, seal_all) / n,
        "verify": best_of(repeat, verify_all) / n,
        "mean_bytes": sum(map(len, airs)) / n,
        "max_bytes": max(map(len, airs)),
        "trailer_bytes": min(map(len, sealed)) - min(map(len, airs)),
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--bundles", type=int, default=6000)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    f = measure(args.bundles, args.repeat, args.seed)
    us = {k: f[k] * 1e6 for k in ("encode", "decode", "seal", "verify")}
    for k, v in us.items():
        print(f"{k:7s} {v:7.2f} us per bundle")
    print(f"seal / encode   {us['seal'] / us['encode']:.2f}")
    print(f"verify / decode {us['verify'] / us['decode']:.2f}")
    both = (us["seal"] + us["verify"]) / (us["encode"] + us["decode"])
    print(f"(seal + verify) / (encode + decode) {both:.2f}")
    t = f["trailer_bytes"]
    print(
        f"bytes per bundle: +{t:.0f} (mean bundle {f['mean_bytes']:.0f} bytes: "
        f"+{100 * t / f['mean_bytes']:.1f}%; largest sealed {f['max_bytes'] + t:.0f} of "
        f"{A.MAX_SEALED_AIR_BYTES})"
    )
    print(f"({args.bundles} bundles, best of {args.repeat})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
