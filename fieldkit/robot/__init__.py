"""One robot, wherever it runs: the tick, the script API, the safety supervisor.

`RobotRuntime` is what the simulator, the field node and SITL share: the Buzz VM, the
script's API, the supervisor between script and vehicle, and the table of robots heard.
Hosts feed it bundles and `Sensors` and get back a bundle to send and an `Order`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fieldkit.robot.rc import RcCommand
    from fieldkit.robot.runtime import RobotRuntime, ScriptStatus, TickOutput, TickRecord
    from fieldkit.robot.safety import Order, OrderKind, Supervisor
    from fieldkit.robot.script_api import Command, CommandKind, ScriptAPI, Sensors

# Imported on first use: `fieldkit.robot.profiles` (every command reads a profile) must not
# pull in the VM and the script API's numerical libraries with it.
_HOME = {
    "RcCommand": "rc",
    "RobotRuntime": "runtime",
    "ScriptStatus": "runtime",
    "TickOutput": "runtime",
    "TickRecord": "runtime",
    "Order": "safety",
    "OrderKind": "safety",
    "Supervisor": "safety",
    "Command": "script_api",
    "CommandKind": "script_api",
    "ScriptAPI": "script_api",
    "Sensors": "script_api",
}


def __getattr__(name: str) -> Any:
    """The package's names, from their modules on first use (PEP 562)."""
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "Command",
    "CommandKind",
    "Order",
    "OrderKind",
    "RcCommand",
    "RobotRuntime",
    "ScriptAPI",
    "ScriptStatus",
    "Sensors",
    "Supervisor",
    "TickOutput",
    "TickRecord",
]
