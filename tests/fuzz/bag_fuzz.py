"""Fuzzing the bag reader (fieldkit.record) with mutated recordings, seeded.

    python tests/fuzz/bag_fuzz.py --count 20000 --seed 1
    python -m tests.fuzz.bag_fuzz --seconds 600 --seed 1
    python -m tests.fuzz.bag_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. An input is one of four real recordings made at import by `BagWriter` (the
sample of tests/bagdata.py, a few ticks with several chunks: a ROS 2 MCAP bag and a ROS 1 bag,
each closed or as a kill -9 leaves it), mutated: bit flips, interesting bytes, an interesting
u32 or u64 over any field (record lengths, counts, offsets), truncation, extension with zeros
or junk, a range deleted or repeated, two recordings spliced, random bytes of the same size,
an MCAP chunk's records changed with its CRC made right again (so the damage reaches the
record parser and the CDR deserializer), and for closed MCAP bags a mutated metadata.yaml.

The property: `BagReader(path)`, reading every row of every topic, and `bag info`'s
`describe` raise nothing but `BagError` (whose message names a file and carries a hint).
Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import atexit
import random
import shutil
import struct
import sys
import tempfile
import traceback
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

if __package__:
    from . import runner
else:  # run as a file: python tests/fuzz/bag_fuzz.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import runner

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bagdata import Sample  # noqa: E402

from fieldkit.record.bag import BagError, BagReader, BagWriter  # noqa: E402
from fieldkit.record.info import describe  # noqa: E402

BASES = ("mcap", "mcap-cut", "ros1", "ros1-cut")
INTERESTING_BYTES = (0x00, 0x01, 0x02, 0x05, 0x06, 0x0F, 0x7F, 0x80, 0xFE, 0xFF)
INTERESTING_INTS = (0, 1, 2, 7, 8, 9, 0x7F, 0xFF, 0x100, 0xFFFF, 0x10000, 0x7FFFFFFF,
                    0x80000000, 0xFFFFFFFF, 1 << 32, 1 << 40, (1 << 63) - 1, 1 << 63,
                    (1 << 64) - 1)  # fmt: skip
#: Slice of a counted campaign between two progress lines (inputs are slow: files and I/O).
SLICE = 500
TICKS = 9


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    opened: int = 0  # inputs BagReader opened
    read_through: int = 0  # inputs whose every row read without error
    rows: int = 0
    refused: int = 0  # inputs that ended in a BagError

    def details(self) -> list[str]:
        """The kinds of input run, and what the reader made of them."""
        return [
            *super().details(),
            f"opened: {self.opened}, read through: {self.read_through}, rows: {self.rows}, "
            f"refused with BagError: {self.refused}",
        ]


# ---------------------------------------------------------------- the recordings


@dataclass(frozen=True)
class Base:
    """A recording as files: {relative path: bytes}; `main` is the file mutations aim at."""

    name: str
    files: dict[str, bytes]
    main: str
    bag: str  # the path BagReader is given, relative


def _record(root: Path, name: str, closed: bool) -> Base:
    """Record the sample into `root/name`; as files."""
    ros1 = name.startswith("ros1")
    bag = "rec.bag" if ros1 else "rec"
    where = root / name
    where.mkdir()
    now = [0.0]
    sample = Sample("fuzz")
    w = BagWriter(where / bag, flush_s=0.25, fsync=False, clock=lambda: now[0])
    w.meta(sample.meta)
    for k in range(TICKS):
        sample.write_tick(w, k)
        now[0] = (k + 1) * 0.1
    if closed:
        w.close()
    files = {str(p.relative_to(where)): p.read_bytes() for p in where.rglob("*") if p.is_file()}
    if not closed:
        w.close()  # the files were taken before: as a kill -9 leaves them
    main = bag if ros1 else f"{bag}/{bag}.mcap"
    return Base(name, files, main, bag)


_bases: dict[str, Base] = {}
_workdir: list[Path] = []


def bases() -> dict[str, Base]:
    """The four recordings (made once)."""
    if not _bases:
        root = Path(tempfile.mkdtemp(prefix="bag-fuzz-bases-"))
        try:
            for name in BASES:
                _bases[name] = _record(root, name, closed=not name.endswith("-cut"))
        finally:
            shutil.rmtree(root, ignore_errors=True)
    return _bases


def workdir() -> Path:
    """A scratch folder for the inputs' files (one per process)."""
    if not _workdir:
        folder = Path(tempfile.mkdtemp(prefix="bag-fuzz-"))
        atexit.register(shutil.rmtree, folder, True)  # whoever ran the inputs: a campaign, a test
        _workdir.append(folder)
    return _workdir[0]


# ---------------------------------------------------------------- mutations


def _mcap_chunks(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of the chunk records' contents of an MCAP file (a walk that stops at
    the first record that does not fit)."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        if pos + 9 + length > len(data):
            break
        if op == 0x06:
            out.append((pos + 9, length))
        if op in (0x02, 0x0F):
            break
        pos += 9 + length
    return out


def _chunk_edit(rng: random.Random, data: bytearray) -> str:
    """Change an uncompressed chunk's records and make its CRC right again."""
    chunks = _mcap_chunks(bytes(data))
    if not chunks:
        return "chunk-none"
    start, length = rng.choice(chunks)
    (clen,) = struct.unpack_from("<I", data, start + 28)
    records_at = start + 28 + 4 + clen + 8
    end = start + length
    if records_at >= end:
        return "chunk-none"
    for _ in range(rng.randint(1, 6)):
        at = rng.randrange(records_at, end)
        if rng.random() < 0.5:
            data[at] = rng.choice(INTERESTING_BYTES)
        else:
            data[at] ^= 1 << rng.randrange(8)
    crc = zlib.crc32(bytes(data[records_at:end]))
    struct.pack_into("<I", data, start + 24, crc)
    return "chunk-crc"


def mutate(rng: random.Random, base: Base, other: Base) -> tuple[str, dict[str, bytes]]:
    """(kind, the files of a mutant of `base`; `other` may be spliced in)."""
    files = dict(base.files)
    data = bytearray(files[base.main])
    kinds = ["flip", "byte", "int", "truncate", "extend", "delete", "repeat", "splice", "random"]
    if base.name.startswith("mcap"):
        kinds += ["chunk", "chunk"]  # the CRC made right: damage that reaches the parsers
    if f"{base.bag}/metadata.yaml" in files:
        kinds.append("yaml")
    kind = rng.choice(kinds)
    n = len(data)
    if kind == "flip":
        for _ in range(rng.choice((1, 1, 2, 4, 16))):
            data[rng.randrange(n)] ^= 1 << rng.randrange(8)
    elif kind == "byte":
        for _ in range(rng.choice((1, 2, 8))):
            data[rng.randrange(n)] = rng.choice(INTERESTING_BYTES)
    elif kind == "int":
        width = rng.choice((4, 8))
        at = rng.randrange(max(1, n - width))
        value = rng.choice(INTERESTING_INTS) % (1 << (8 * width))
        data[at : at + width] = value.to_bytes(width, "little")
    elif kind == "truncate":
        del data[rng.randrange(n) :]
    elif kind == "extend":
        data += bytes(rng.randint(1, 5000)) if rng.random() < 0.5 else rng.randbytes(5000)
    elif kind == "delete":
        a = rng.randrange(n)
        del data[a : a + rng.randint(1, 2000)]
    elif kind == "repeat":
        a = rng.randrange(n)
        b = min(n, a + rng.randint(1, 2000))
        data[b:b] = data[a:b]
    elif kind == "splice":
        theirs = other.files[other.main]
        data = data[: rng.randrange(n)] + theirs[rng.randrange(len(theirs)) :]
    elif kind == "random":
        data = bytearray(rng.randbytes(n))
    elif kind == "chunk":
        kind = _chunk_edit(rng, data)
    elif kind == "yaml":
        meta = f"{base.bag}/metadata.yaml"
        text = bytearray(files[meta])
        for _ in range(rng.randint(1, 4)):
            at = rng.randrange(len(text))
            choice = rng.random()
            if choice < 0.4:
                del text[at : at + rng.randint(1, 40)]
            elif choice < 0.7:
                text[at] = rng.choice(b"0123456789:-[]{}' \n\x00")
            else:
                text[at:at] = rng.choice((b"9999999999", b"\n- x", b": {", b"mcap", b"'"))
        files[meta] = bytes(text)
    files[base.main] = bytes(data)
    return kind, files


def make_input(seed: str, k: int) -> tuple[str, Base, dict[str, bytes]]:
    """(kind, base, mutated files) of input k."""
    rng = random.Random(f"{seed}:{k}")
    all_bases = bases()
    base = all_bases[rng.choice(BASES)]
    other = all_bases[rng.choice(BASES)]
    kind, files = mutate(rng, base, other)
    return kind, base, files


# ---------------------------------------------------------------- the check


def check(
    base: Base, files: dict[str, bytes], where: Path, stats: Stats | None = None
) -> str | None:
    """Write the files under `where`, read them as a bag; the failure, or None."""
    for rel, content in files.items():
        path = where / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content)
    try:
        r = BagReader(where / base.bag)
        if stats is not None:
            stats.opened += 1
        rows = sum(1 for _ in r.rows())
        describe(r)
        if stats is not None:
            stats.read_through += 1
            stats.rows += rows
    except BagError as e:
        if stats is not None:
            stats.refused += 1
        text = str(e)
        if "\nhint: " not in text or not e.problem or not e.hint:
            return f"a BagError without its place, problem or hint: {text!r}"
    except Exception:  # noqa: BLE001 - what the property forbids
        return "raised:\n" + traceback.format_exc()
    return None


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k and check it."""
    kind, base, files = make_input(seed, k)
    stats.kinds[f"{base.name}/{kind}"] += 1
    where = workdir() / str(k)
    try:
        failure = check(base, files, where, stats)
    finally:
        shutil.rmtree(where, ignore_errors=True)
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({base.name}/{kind}): {failure}", out, shown=20)


run = runner.make_run(run_one, Stats)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, base, files = make_input(seed, int(k))
    print(f"{base.name}, {kind}: " + ", ".join(f"{p} ({len(b)} bytes)" for p, b in files.items()))
    where = workdir() / "replay"
    try:
        failure = check(base, files, where)
        if failure is None:
            try:
                print(describe(BagReader(where / base.bag)))
            except BagError as e:
                print(f"BagError: {e}")
    finally:
        shutil.rmtree(where, ignore_errors=True)
    print(failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: --count N runs exactly N inputs (no time limit)."""
    return runner.counted_main(argv, __doc__, run, replay, Stats, slice_inputs=SLICE)


if __name__ == "__main__":
    sys.exit(main())
