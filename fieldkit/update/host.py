"""The update's place in a robot's tick, the same for the simulator, the node and SITL.

`RobotUpdater` joins a robot's `RobotRuntime` and its `UpdateAgent`. The host calls it at
three points of the one-way tick:

    radio in    `receive(frame)`: an update frame goes to the agent (True), anything else
                is the host's (a bundle for the runtime)
    step        `before_step(sensors)`: the agent's decision carried out on the runtime
                (stand by, resume, switch, roll back) before the script steps
    radio out   `after_step()`: the agent learns a script error of this step (in grace it
                rolls the version back) and hands over its frame, if any

`on_change`, if given, sees every action carried out (a store commits versions there), and
`on_patch` every patch that checked out (a store keeps it for neighbours that catch up).
"""

from __future__ import annotations

from collections.abc import Callable

from fieldkit.robot.runtime import RobotRuntime, ScriptStatus
from fieldkit.robot.script_api import Sensors
from fieldkit.update import packets as pk
from fieldkit.update.agent import Action, Resume, Standby, UpdateAgent


class RobotUpdater:
    """One robot's runtime and update agent, driven from its host's tick."""

    def __init__(
        self,
        runtime: RobotRuntime,
        agent: UpdateAgent,
        *,
        log: Callable[[str], None] | None = None,
        on_change: Callable[[Action], None] | None = None,
        on_patch: Callable[[int, bytes], None] | None = None,
    ) -> None:
        """`log` takes each line worth the operator's attention (versions, refusals)."""
        self.runtime = runtime
        self.agent = agent
        self.log = log
        self.on_change = on_change
        self.on_patch = on_patch
        self.actions: list[tuple[int, Action]] = []  # (tick, action), what the robot did
        self._failed_seen: str | None = None

    def receive(self, data: bytes) -> bool:
        """A frame off the radio: True if it was the update's (kept), False if a bundle's."""
        kind = pk.frame_type(data)
        if kind == pk.UPDATE_FRAME:
            self.agent.receive(data)
            return True
        if kind == pk.ROSBUZZ_OTA:
            # ROSBuzz's unsigned SENT_CODE / RESEND_CODE: never applied, only counted.
            agent = self.agent
            agent.counters["rosbuzz_ota_refused"] += 1
            if agent.counters["rosbuzz_ota_refused"] == 1:
                agent.events.append("a ROSBuzz OTA packet (unsigned) was refused")
            return True
        return False

    def inject(self, patch: bytes) -> bool:
        """A whole patch made on this robot (the originator's outbox): verified as if
        received, then served to the neighbours; True if it checked out. Its verdict is
        logged at once, and a patch that checked out is kept (`on_patch`)."""
        ok = self.agent.inject(patch)
        self._flush()
        return ok

    def before_step(self, sensors: Sensors) -> None:
        """Carry out the agent's decision for this tick on the runtime."""
        self._note_failure()
        action = self.agent.tick(self.runtime.ticks)
        if action is not None:
            self._apply(action, sensors)
        self._flush()

    def after_step(self) -> bytes | None:
        """This tick's update frame (None: nothing to send)."""
        self._note_failure()
        self._flush()
        return self.agent.frame()

    def _note_failure(self) -> None:
        runtime = self.runtime
        if runtime.status is ScriptStatus.FAILED and runtime.error != self._failed_seen:
            self._failed_seen = runtime.error
            # The error's first line (its place and problem), not the Buzz call stack.
            self.agent.script_failed((runtime.error or "script error").splitlines()[0])

    def _apply(self, action: Action, sensors: Sensors) -> None:
        runtime = self.runtime
        self.actions.append((runtime.ticks, action))
        if isinstance(action, Standby | Resume):
            if isinstance(action, Standby):
                runtime.stand_by(f"update to version {action.version}: waiting for the swarm")
                self.agent.events.append(
                    f"standing by for version {action.version}: holding until the swarm agrees"
                )
            else:
                runtime.resume()
                self.agent.events.append(f"version {action.version} abandoned: script resumed")
            if self.on_change is not None:
                self.on_change(action)
            return
        # Switch or Rollback: a new program, started as the robot starts one (global code,
        # init()), with the host's state (flight status, position, home) untouched.
        self._failed_seen = None
        try:
            program = action.release.program(f"version {action.version}")
        except Exception as e:  # verified before, so only a bug or a bad store gets here
            runtime.fail(f"version {action.version} does not load: {e}")
        else:
            runtime.start(program, sensors)
        if self.on_change is not None:
            self.on_change(action)
        self._note_failure()  # an init() that fails is a failure in grace

    def _flush(self) -> None:
        verified = self.agent.verified
        if verified:
            if self.on_patch is not None:
                for version, data in verified:
                    self.on_patch(version, data)
            verified.clear()
        events = self.agent.events
        if events and self.log is not None:
            for line in events:
                self.log(line)
        events.clear()


__all__ = ["RobotUpdater"]
