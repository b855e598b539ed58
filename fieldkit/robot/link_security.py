"""One robot's radio security setting: seal the bundles it sends, check the ones it hears.

Two modes (docs/security.md#modes):

* `signed`: every bundle sent gets the 16-byte trailer of `bundle_auth` (a per-sender
  counter, a tag under the swarm key); a bundle heard must pass `Verifier.verify` before a
  byte of it is decoded. The bundle gives up one word for the trailer, so the Buzz budget is
  `SEALED_MAX_MSG_SIZE` (184 bytes of content) instead of ROSBuzz's 190.
* `none`: the plain bytes of ROSBuzz, as before. A sealed bundle heard is dropped (this
  robot could not check it) and counted.

Either way a neighbour on the other setting is reported once, by robot id, as mixed settings
(`mixed`): a swarm split in two by its settings says so instead of partitioning silently.
The runtime calls `open` on every bundle it hears and `seal` on every bundle it sends;
the host chooses the mode and gives the keys and the counter store.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Final, Literal

from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import bundle_auth as auth
from fieldkit.robot.profiles import SECURITY_MODES

Mode = Literal["signed", "none"]
SIGNED: Final = "signed"
NONE: Final = "none"
#: The settings, as `--security` and a profile's `[radio] security` take them.
MODES: Final = SECURITY_MODES

#: What a `none` robot counts for a sealed bundle it dropped.
SEALED: Final = "sealed"
#: What a `none` robot counts for a plain bundle it passed on to the decoder.
PLAIN: Final = "plain"
#: A bundle of this robot's own id: its own, echoed back by a mesh (or replayed to it).
OWN_ECHO: Final = "own-echo"


class LinkSecurity:
    """A robot's security mode: `seal` what it sends, `open` what it hears, counting both."""

    def __init__(
        self,
        robot_id: int,
        mode: Mode,
        *,
        sealer: auth.Sealer | None = None,
        verifier: auth.Verifier | None = None,
        floors: auth.FloorStore | None = None,
        report: Callable[[str], None] | None = None,
    ) -> None:
        """`signed` needs a `sealer` and a `verifier` (see `signed`); `floors`, if given, is
        where the verifier's floors are saved (`save_floors`); `report` takes each line
        about a neighbour on other settings."""
        if mode not in MODES:
            raise ValueError(f"security mode must be one of {', '.join(MODES)}, got {mode!r}")
        if mode == SIGNED and (sealer is None or verifier is None):
            raise ValueError("signed mode needs a sealer and a verifier")
        self.robot_id = robot_id
        self.mode: Mode = mode
        self.signed = mode == SIGNED
        self.sealer = sealer
        self.verifier = verifier
        self.floors = floors
        self.report = report
        #: Bundle content limit (header, length prefixes, messages) in this mode.
        self.max_content = auth.SEALED_MAX_MSG_SIZE if self.signed else wirebundle.MAX_MSG_SIZE
        #: In `none` mode: PLAIN and SEALED; in `signed` mode the verifier counts.
        self.counters: Counter[str] = Counter() if verifier is None else verifier.counters
        #: Neighbours heard on other settings: robot id -> what was seen (reported once).
        self.mixed: dict[int, str] = {}

    @classmethod
    def signed_with(
        cls,
        robot_id: int,
        key: auth.BundleKey,
        counters: auth.CounterSource,
        *,
        floors: auth.FloorStore | None = None,
        report: Callable[[str], None] | None = None,
    ) -> LinkSecurity:
        """`signed` mode under `key`, counters from `counters`; the verifier starts from
        the floors saved in `floors`, if given (a receiver reboot)."""
        sealer = auth.Sealer(robot_id, key, counters)
        verifier = auth.Verifier(key, floors=floors.load() if floors is not None else None)
        return cls(robot_id, SIGNED, sealer=sealer, verifier=verifier, floors=floors, report=report)

    # ------------------------------------------------------------ out

    def seal(self, air: bytes) -> bytes:
        """The bytes to send for a bundle's air bytes: sealed in `signed` mode, else as is.
        Raises CounterError if no counter can be had (the state directory is unwritable)."""
        sealer = self.sealer
        return air if sealer is None else sealer.seal(air)

    @property
    def last_counter(self) -> int:
        """The counter of the last bundle sealed (0 in `none` mode, or before any)."""
        return 0 if self.sealer is None else self.sealer.last

    # ------------------------------------------------------------ in

    def open(self, data: bytes) -> bytes | None:
        """The plain bundle bytes to decode, or None: dropped, and counted by reason."""
        verifier = self.verifier
        if len(data) >= wirebundle.MIN_AIR_BYTES and auth.bundle_sender(data) == self.robot_id:
            # No window of its own counters: a replay of them would pass the verifier.
            self.counters[OWN_ECHO] += 1
            return None
        if verifier is None:
            if auth.is_sealed(data):
                self.counters[SEALED] += 1
                self._mixed(
                    auth.bundle_sender(data),
                    "sends sealed bundles (--security signed): this robot runs `none` and "
                    "drops them",
                )
                return None
            self.counters[PLAIN] += 1
            return data
        try:
            return verifier.verify(data)
        except auth.AuthError as e:
            if e.sender is not None and e.reason == auth.MISSING_TRAILER:
                self._mixed(
                    e.sender,
                    "sends plain bundles (--security none, or a ROSBuzz robot): this robot "
                    "runs `signed` and drops them",
                )
            elif e.sender is not None and e.reason == auth.UNKNOWN_KEY:
                self._mixed(e.sender, f"seals with another swarm key ({e.what}): dropped")
            return None

    def admit(self, sender: int, counter: int) -> bool:
        """For a host that sealed the bundle itself under the same key (the simulator):
        pass its counter through this robot's replay window; whether it is accepted."""
        verifier = self.verifier
        if verifier is None:
            return True
        try:
            verifier.admit(sender, counter)
        except auth.AuthError:
            return False
        return True

    def _mixed(self, sender: int, what: str) -> None:
        if sender in self.mixed or sender == self.robot_id:
            return
        self.mixed[sender] = what
        if self.report is not None:
            self.report(f"mixed security settings: robot {sender} {what}")

    # ------------------------------------------------------------ state

    def save_floors(self, *, now: bool = False) -> bool:
        """Save the verifier's floors if they moved far enough (once a minute at 10 Hz), or
        `now` (a clean stop); whether it wrote. CounterError if the file cannot be written."""
        if self.floors is None or self.verifier is None:
            return False
        if now:
            self.floors.save(self.verifier.floors())
            return True
        return self.floors.save_if_due(self.verifier.floors())

    def rejected(self) -> dict[str, int]:
        """Bundles dropped so far, by reason (none mode: SEALED)."""
        reasons = (*auth.REASONS, OWN_ECHO) if self.signed else (SEALED, OWN_ECHO)
        return {r: self.counters[r] for r in reasons if self.counters[r]}

    def summary(self) -> dict[str, object]:
        """What a run's summary says of this robot's link security."""
        return {
            "mode": self.mode,
            "accepted": self.counters[auth.ACCEPTED if self.signed else PLAIN],
            "rejected": self.rejected(),
            "mixed": {str(s): w for s, w in sorted(self.mixed.items())},
        }


__all__ = ["LinkSecurity", "MODES", "Mode", "NONE", "OWN_ECHO", "PLAIN", "SEALED", "SIGNED"]
