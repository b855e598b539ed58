"""A fuzzing campaign without hypothesis's example cap: a seeded random loop.

    python -m tests.fuzz.campaign --minutes 10 --seed 1               # both fuzzers
    python -m tests.fuzz.campaign --minutes 5 --seed 2 --mode diff    # differential only
    python -m tests.fuzz.campaign --minutes 5 --seed 3 --mode loader  # loader only

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so any input can be replayed
with `--replay S:k`. Every failure is saved under tests/fuzz/crashes/ (the Buzz source or
the .bo/.bdb, plus a .txt with the verdict), at most `--per-signature` per distinct failure
signature. Known open VM bugs (oracle.KNOWN_BUGS) are counted separately, not as failures,
unless `--no-known` is given. The last line printed is `inputs: N, failures: K`.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import os
import random
import re
import resource
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import bvm

from . import oracle
from .choosers import RandomChooser
from .inputs import loader_input, source_input

CRASH_DIR = Path(__file__).resolve().parent / "crashes"


def _signature(text: str) -> str:
    """A failure signature: the text without numbers (offsets, values), quotes, call args."""
    text = re.sub(r"call \w+\(.*?\): ", "call: ", text)
    text = re.sub(r"\d+", "N", text)
    text = re.sub(r"'[^']*'", "'…'", text)
    return text[:160]


class Campaign:
    """Counts inputs and failures, saves failures."""

    def __init__(self, seed: str, *, per_signature: int, known: bool, timeout: float) -> None:
        self.seed = seed
        self.per_signature = per_signature
        self.known = known
        self.timeout = timeout
        self.inputs: collections.Counter[str] = collections.Counter()
        self.kinds: collections.Counter[str] = collections.Counter()
        self.failures = 0
        self.signatures: collections.Counter[str] = collections.Counter()
        self.saved: list[Path] = []

    # ------------------------------------------------------------ saving

    def fail(self, mode: str, k: int, sig: str, detail: str, files: dict[str, bytes]) -> None:
        """Record one failure; save it unless this signature was saved often enough."""
        self.failures += 1
        self.signatures[sig] += 1
        if self.signatures[sig] > self.per_signature:
            return
        CRASH_DIR.mkdir(parents=True, exist_ok=True)
        tag = hashlib.sha1(sig.encode()).hexdigest()[:8]
        stem = CRASH_DIR / f"{mode}-{self.seed}-{k}-{tag}"
        for ext, data in files.items():
            stem.with_suffix(ext).write_bytes(data)
        replay = f"--replay {self.seed}:{k} --mode {mode}"
        stem.with_suffix(".txt").write_text(f"signature: {sig}\nreplay: {replay}\n\n{detail}\n")
        self.saved.append(stem)
        print(f"  FAILURE [{mode} {self.seed}:{k}] {sig}", flush=True)

    # ------------------------------------------------------------ one input

    def run_diff(self, k: int) -> str:
        """One differential input; returns its verdict kind."""
        ch = RandomChooser(random.Random(f"{self.seed}:{k}"))
        g = source_input(ch)
        funcs = [(f.name, f.nparams) for f in g.functions]
        files = {".bzz": g.source.encode()}
        try:
            program = bvm.compile_source(g.source, "/fuzz/prog.bzz")
        except bvm.BuzzCompileError as e:
            self.fail("diff", k, "generator: does not compile", str(e), files)
            return "generator-error"
        rss = oracle.max_rss_mib()
        try:
            with oracle.deadline(self.timeout):
                v = oracle.run_both(program, funcs, known=self.known)
        except oracle.Hang as e:
            self.fail("diff", k, "hang", str(e), files)
            return "hang"
        if oracle.max_rss_mib() - rss > 512:
            self.fail("diff", k, "memory: +512 MiB", "", files)
        if not v.ok:
            first = v.detail.splitlines()[0] if v.kind == "crash" else ""
            sig = _signature(f"{v.kind}: {first or _mismatch_shape(v.detail)}")
            detail = f"functions: {funcs}\n{v.kind}\n{v.detail}"
            self.fail("diff", k, sig, detail, files)
        return v.kind

    def run_loader(self, k: int) -> str:
        """One loader input: the loader property, both paths, and their agreement."""
        ch = RandomChooser(random.Random(f"{self.seed}:{k}"))
        bo, bdb, origin = loader_input(ch)
        files = {".bo": bo, ".bdb": bdb}
        rss = oracle.max_rss_mib()
        try:
            # Four runs (two paths, then the differential), each up to max_ticks=10_000
            # loop iterations: interpreted hostile code takes up to ~5 s per run.
            with oracle.deadline(3 * self.timeout):
                paths = (True, False)
                results = [
                    oracle.check_loader(bo, bdb, translate=t, known=self.known) for t in paths
                ]
                verdict = None
                if results[0].stage != "rejected":
                    program = bvm.Program(bo, bdb, "/fuzz/input.bo")
                    verdict = oracle.run_both(
                        program, [], max_ticks=10_000, call_rounds=(), known=self.known
                    )
        except oracle.Hang as e:
            self.fail("loader", k, f"hang ({origin})", str(e), files)
            return "hang"
        if oracle.max_rss_mib() - rss > 512:
            self.fail("loader", k, f"memory: +512 MiB ({origin})", "", files)
        for r, path in zip(results, ("translated", "interpreted"), strict=True):
            if r.problem:
                sig = _signature(f"loader {path}: {r.problem}")
                self.fail("loader", k, sig, f"{origin}\n{r.stage}: {r.problem}", files)
                return "crash"
        for r in results:
            if r.known:
                return f"known:{r.known}"
        if verdict is not None and not verdict.ok:
            first = verdict.detail.splitlines()[0] if verdict.kind == "crash" else ""
            sig = _signature(f"mutant {verdict.kind}: {first or _mismatch_shape(verdict.detail)}")
            self.fail("loader", k, sig, f"{origin}\n{verdict.kind}\n{verdict.detail}", files)
            return verdict.kind
        return results[0].stage if verdict is None else f"{results[0].stage}/{verdict.kind}"

    # ------------------------------------------------------------ loop

    def run(self, modes: list[str], seconds: float) -> None:
        """Alternate the modes until the time is up."""
        end = time.monotonic() + seconds
        k = 0
        last = time.monotonic()
        while time.monotonic() < end:
            mode = modes[k % len(modes)]
            try:
                kind = self.run_diff(k) if mode == "diff" else self.run_loader(k)
            except Exception:  # noqa: BLE001 - a harness error is a failure too
                tb = traceback.format_exc()
                self.fail(mode, k, _signature("harness: " + tb.splitlines()[-1]), tb, {})
                kind = "harness-error"
            self.inputs[mode] += 1
            self.kinds[f"{mode}:{kind}"] += 1
            k += 1
            if time.monotonic() - last > 30:
                last = time.monotonic()
                print(f"  ... {dict(self.inputs)} failures {self.failures}", flush=True)

    def report(self) -> None:
        """Print the summary; the last line is `inputs: N, failures: K`."""
        print("per mode:", dict(self.inputs))
        print("outcomes:", dict(sorted(self.kinds.items())))
        for sig, n in self.signatures.most_common():
            print(f"  {n:6d}  {sig}")
        print(f"inputs: {sum(self.inputs.values())}, failures: {self.failures}")


def _mismatch_shape(detail: str) -> str:
    """The kind of the first differing events (e.g. `log` vs `execute -> BuzzError...`)."""
    lines = [ln.strip() for ln in detail.splitlines() if ln.strip()]
    parts = []
    for ln in lines[1:3]:
        body = ln.split(":", 1)[-1].strip()
        parts.append(re.sub(r"\[.*", "", body)[:60])
    return " / ".join(parts)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--minutes", type=float, default=1.0)
    ap.add_argument("--seed", default="0")
    ap.add_argument("--mode", choices=["all", "diff", "loader"], default="all")
    ap.add_argument("--per-signature", type=int, default=3, help="failures saved per signature")
    ap.add_argument("--no-known", action="store_true", help="count known bugs as failures")
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds allowed per input")
    ap.add_argument("--memory-mb", type=int, default=4096, help="address-space limit")
    ap.add_argument("--replay", help="SEED:K -- run one input verbosely")
    args = ap.parse_args(argv)
    # Fuzzed programs call io.fopen relative to the cwd: give them a scratch directory.
    os.chdir(tempfile.mkdtemp(prefix="bvm-fuzz-"))
    # Translated code that is certain to fail (e.g. `'abc'['x']`) draws SyntaxWarnings.
    warnings.simplefilter("ignore", SyntaxWarning)
    if args.memory_mb:
        limit = args.memory_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 1000))
    if args.replay:
        seed, k = args.replay.rsplit(":", 1)
        c = Campaign(seed, per_signature=0, known=not args.no_known, timeout=args.timeout)
        mode = "loader" if args.mode == "loader" else "diff"
        if mode == "diff":
            g = source_input(RandomChooser(random.Random(f"{seed}:{k}")))
            print(g.source)
            print("functions:", [(f.name, f.nparams) for f in g.functions])
            print("verdict:", c.run_diff(int(k)))
        else:
            print("verdict:", c.run_loader(int(k)))
        return 0
    modes = ["diff", "loader"] if args.mode == "all" else [args.mode]
    c = Campaign(
        args.seed, per_signature=args.per_signature, known=not args.no_known, timeout=args.timeout
    )
    print(f"campaign seed {args.seed}, modes {modes}, {args.minutes} min", flush=True)
    c.run(modes, args.minutes * 60)
    c.report()
    return 1 if c.failures else 0


if __name__ == "__main__":
    sys.exit(main())
