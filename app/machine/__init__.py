"""Controller adapters behind one small interface (see base.py); build one with make_controller."""

from app.machine.base import (SLOT_P_NUMBERS, Controller, ControllerError, MachinePosition, NoOffsetYet,
                              PositionUnavailable, WorkOffset, slot_name, slot_number)
from app.machine.settings import ControllerSettings, make_controller, parse_controller_settings

__all__ = [
    "SLOT_P_NUMBERS", "Controller", "ControllerError", "ControllerSettings", "MachinePosition", "NoOffsetYet",
    "PositionUnavailable", "WorkOffset",
    "make_controller", "parse_controller_settings", "slot_name", "slot_number",
]
