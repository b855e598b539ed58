"""One robot, wherever it runs: the tick, the script API, the safety supervisor.

`RobotRuntime` is what the simulator, the field node and SITL share: the Buzz VM, the
script's API, the supervisor between script and vehicle, and the table of robots heard.
Hosts feed it bundles and `Sensors` and get back a bundle to send and an `Order`.
"""

from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import RobotRuntime, ScriptStatus, TickOutput, TickRecord
from fieldkit.robot.safety import Order, OrderKind, Supervisor
from fieldkit.robot.script_api import Command, CommandKind, ScriptAPI, Sensors

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
