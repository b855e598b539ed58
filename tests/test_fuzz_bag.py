"""Bag reader fuzzing: a short deterministic campaign slice, and proof that the harness's
check catches a reader that lets another exception out.

Long campaigns: `python tests/fuzz/bag_fuzz.py --count 20000 --seed S` (see that module).
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from fuzz import bag_fuzz as F

from fieldkit.record import bag as B


def test_campaign_slice() -> None:
    """160 fixed inputs over the four recordings: only BagError comes out; every base and
    the mutations that reach deep (a chunk with its CRC made right) are among them."""
    lines: list[str] = []
    stats = F.run("ci", max_inputs=160, out=lines.append)
    assert stats.inputs == 160
    assert stats.failures == 0, "\n".join(lines)
    bases = {kind.split("/")[0] for kind in stats.kinds}
    assert bases == set(F.BASES)
    assert any(kind.endswith("/chunk-crc") for kind in stats.kinds)
    assert stats.refused > 20 and stats.read_through > 20 and stats.opened > stats.refused / 4


def test_the_mutants_are_not_all_refused_or_all_read() -> None:
    """The CRC-fixed chunk edits get past the checksum to the records (else the harness
    would only ever test the CRC check)."""
    base = F.bases()["mcap-cut"]
    data = bytearray(base.files[base.main])
    kinds = {F._chunk_edit(random.Random(i), data) for i in range(5)}
    assert kinds == {"chunk-crc"}
    for start, length in F._mcap_chunks(bytes(data)):
        assert length > 0 and start < len(data)


def test_the_check_catches_an_escaping_exception(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    base = F.bases()["ros1"]
    assert F.check(base, dict(base.files), tmp_path / "ok") is None

    def broken(topic: str, msg: object, stamp: int) -> B.Row:
        raise KeyError("a bug")

    monkeypatch.setattr(B, "_to_row", broken)
    # The reader turns it into a BagError (a message that does not decode)...
    assert F.check(base, dict(base.files), tmp_path / "a") is None

    def worse(self: B.BagReader, *topics: str) -> object:
        raise IndexError("a bug outside the guarded reads")

    monkeypatch.undo()
    monkeypatch.setattr(B.BagReader, "rows", worse)
    failure = F.check(base, dict(base.files), tmp_path / "b")
    assert failure is not None and "IndexError" in failure
